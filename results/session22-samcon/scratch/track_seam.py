"""``track-samcon`` with the motion library's loop-seam bridge set (``seam_bridge``, seconds; 0: off, the default).

    python track_seam.py 0.1 --config configs/samcon/polish.yaml --set train.seed=1 --motions zombie_walk --out DIR

Session 22's runs on the bridged references (``bridge-*``, ``seed*``, ``search-new-s*``) were made while the bridge
was the library's default (commit 98bbe92), with plain ``track-samcon``; ``track_seam.py 0.1`` repeats them since.
The ``search-old-s*`` runs were made with ``track_seam.py 0`` (then a copy named ``track_unbridged.py``).
"""

import sys

from common.motion import library
from samcon import track

width = float(sys.argv.pop(1))
library.resample_clip.__defaults__ = (width,)
library.MotionLibrary.from_clips.__func__.__defaults__ = (width,)
sys.exit(track.main())
