"""Joint maps: which source (BVH) joint drives each body of the character, as YAML.

A map has ``up`` (the source's up axis, ``y`` or ``z``), ``bodies`` (character body -> source joints that may drive
it, the first one found in the file wins, so one map covers naming variants) and ``tips`` (for bodies with no mapped
child: the source joint or End Site ``JOINT/end`` their tip points at, and that direction in the character's body
frame at its zero pose). Presets live beside this module (``maps/*.yaml``); a user map is any YAML file of that form.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from common.config import parse_yaml
from common.motion.errors import MotionFormatError
from common.motion.limits import check_regular_file

UP_AXES = ("y", "z")


@dataclass(frozen=True)
class Tip:
    """Where a leaf body points: ``source`` candidates (joint or ``JOINT/end``) and ``along`` (3,), body frame.

    ``with_parent``: the body's rotation comes, frame by frame, from its tip and its parent's bone alone (the tip
    exactly, the parent bone as near as possible), not from the source joint's frame: for feet, whose roll in CMU
    data follows the skeleton's splayed rest legs rather than the ground (the ankle's inversion is taken as zero).
    """

    source: tuple[str, ...]
    along: np.ndarray
    with_parent: bool = False


@dataclass(frozen=True)
class JointMap:
    """A parsed joint map (see the module docstring).

    Attributes:
        name: Preset name or file.
        up: Source up axis, ``"y"`` or ``"z"``.
        bodies: Character body -> candidate source joint names, in order of preference.
        tips: Leaf character body -> its tip.
    """

    name: str
    up: str
    bodies: dict[str, tuple[str, ...]]
    tips: dict[str, Tip]


def preset_names() -> list[str]:
    return sorted(p.stem for p in Path(str(resources.files("common.motion.motion_import") / "maps")).glob("*.yaml"))


def _names(value: object, where: str) -> tuple[str, ...]:
    names = (value,) if isinstance(value, str) else value
    if not isinstance(names, list | tuple) or not names or not all(isinstance(n, str) for n in names):
        raise MotionFormatError(f"{where}: expected a joint name or a list of them, got {value!r}")
    return tuple(names)


def parse_joint_map(doc: object, source: str, bodies: tuple[str, ...]) -> JointMap:
    """Validates a joint map document.

    Args:
        doc: The parsed YAML.
        source: File name for messages.
        bodies: The character's body names (every map key must be one).

    Raises:
        MotionFormatError: naming the file, the key and the problem.
    """
    if not isinstance(doc, dict):
        raise MotionFormatError(f"{source}: a joint map is a mapping with 'up', 'bodies' and 'tips'")
    unknown = sorted(set(doc) - {"up", "bodies", "tips"})
    if unknown:
        raise MotionFormatError(f"{source}: unknown key(s) {unknown}; expected 'up', 'bodies', 'tips'")
    up = str(doc.get("up", "y")).lower()
    if up not in UP_AXES:
        raise MotionFormatError(f"{source}: 'up' must be one of {UP_AXES}, got {doc.get('up')!r}")
    raw = doc.get("bodies")
    if not isinstance(raw, dict) or not raw:
        raise MotionFormatError(f"{source}: 'bodies' must map character bodies to source joints")
    for key in list(raw) + list(doc.get("tips") or {}):
        if key not in bodies:
            raise MotionFormatError(f"{source}: '{key}' is not a body of the character ({', '.join(bodies)})")
    missing = [b for b in bodies if b not in raw]
    if missing:
        raise MotionFormatError(f"{source}: 'bodies' lacks {missing}: every body needs a source joint")
    mapped = {b: _names(v, f"{source}: bodies.{b}") for b, v in raw.items()}
    tips = {}
    for body, tip in (doc.get("tips") or {}).items():
        where = f"{source}: tips.{body}"
        if not isinstance(tip, dict) or not {"source", "along"} <= set(tip) <= {"source", "along", "with_parent"}:
            raise MotionFormatError(f"{where}: expected {{source: [...], along: [x, y, z], with_parent: bool}}")
        if not isinstance(tip.get("with_parent", False), bool):
            raise MotionFormatError(f"{where}.with_parent: expected true or false, got {tip['with_parent']!r}")
        raw_along = tip["along"]
        # Numbers must be numbers: numpy would take ["1", "0", "0"] and [true, 0, 0] for vectors.
        numbers = isinstance(raw_along, list) and all(type(v) in (int, float) for v in raw_along)
        along = np.asarray(raw_along, dtype=np.float64) if numbers else np.zeros(0)
        if along.shape != (3,) or not np.all(np.isfinite(along)) or np.linalg.norm(along) < 1e-9:
            raise MotionFormatError(f"{where}.along: expected a non-zero vector of 3 numbers [x, y, z], got "
                                    f"{repr(raw_along)[:60]}")  # fmt: skip
        tips[body] = Tip(_names(tip["source"], f"{where}.source"), along, bool(tip.get("with_parent", False)))
    return JointMap(source, up, mapped, tips)


def load_joint_map(spec: str | Path, bodies: tuple[str, ...]) -> JointMap:
    """A preset by name (``cmu``, ``humanoid3d``) or a YAML file.

    Raises:
        MotionFormatError: an unknown preset, an unreadable file or an invalid map.
    """
    path = Path(spec)
    if not path.suffix:
        path = Path(str(resources.files("common.motion.motion_import") / "maps" / f"{spec}.yaml"))
        if not path.exists():
            raise MotionFormatError(f"{spec}: no such joint map preset (presets: {', '.join(preset_names())})")
    check_regular_file(path, MotionFormatError)
    try:
        doc = parse_yaml(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise MotionFormatError(f"{path}: cannot read ({e.strerror})") from None
    except Exception as e:  # noqa: BLE001 - any YAML parser error means the same: not a readable map
        raise MotionFormatError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    return parse_joint_map(doc, str(path) if path.stem != str(spec) else str(spec), bodies)
