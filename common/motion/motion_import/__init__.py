"""Motion import: BVH reading and writing, retargeting onto the humanoid, clean-up of clips (trim, mirror, ground,
loop), and the ``mimic-motions import`` / ``render`` pipeline."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def bundled_bvh_dir() -> Path:
    """The folder of the bundled BVH takes (``131_01.bvh``, CMU; see ``common/motion/data/README.md``)."""
    return Path(str(resources.files("common.motion") / "data" / "bvh"))
