"""Terrains for a terrain suite: stairs, slopes, rough ground and boxes, each a seeded function returning a
:class:`~common.motion.terrain.Terrain`.

Every terrain is a strip along +x: flat at height 0 from ``x = -before`` to 0 (where a clip starts), the feature from
0 to ``length``, then flat again for ``after`` metres at the height the feature ended on; ``width`` across y, centred
on y = 0. What is left unset (a step's height, a slope's angle) is drawn from the documented range with ``seed``, so
that one seed gives one terrain. A heightfield has no vertical faces: a step's riser (a box's side) rises across one
cell, so it leans by atan(cell / rise) from the vertical (cell 5 cm, step 10 cm: 27 deg; 2 cm: 11 deg).

The default cells are a trade of shape against speed: MuJoCo collides a geom with each triangular prism of a field on
its own, so a finer grid gives more contacts. The zero pose standing on a field of 2 cm cells has 100 contacts (two
feet at MuJoCo's cap of 50 per geom pair) and simulates 3.9x slower than on the plane's 8 contacts; 5 cm cells: 46
contacts, 2.0x; 10 cm: 20 contacts, 1.5x (one second of physics, one thread, a busy 2-core machine). Stairs and boxes
use 5 cm; slopes and rough ground, whose shape a coarser grid keeps, 10 cm.
"""

from __future__ import annotations

import numpy as np

from common.motion.limits import MAX_TERRAIN_POINTS
from common.motion.terrain import Terrain, check_terrain

STEP_HEIGHT_RANGE = (0.05, 0.15)  # m
SLOPE_ANGLE_RANGE = (5.0, 12.0)  # deg, up or down
ROUGH_AMPLITUDE = 0.03  # m: bumps within +-3 cm
BOX_HEIGHT_RANGE = (0.05, 0.25)  # m: a box a foot steps onto
BOX_SIZE_RANGE = (0.4, 0.8)  # m, side of a box


def _grid(length: float, width: float, before: float, after: float, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """The node coordinates x (cols,) and y (rows,) of a strip from -before to length + after, width across."""
    if not (length > 0 and width > 0 and before >= 0 and after >= 0 and cell > 0):
        raise ValueError(f"a terrain needs length, width and cell > 0 and before, after >= 0, got {length}, {width}, "
                         f"{cell}, {before}, {after}")  # fmt: skip
    cols = int(np.ceil((before + length + after) / cell - 1e-9)) + 1
    rows = int(np.ceil(width / cell - 1e-9)) + 1
    if rows * cols > MAX_TERRAIN_POINTS:  # before anything that size is allocated
        raise ValueError(f"a terrain of {rows:,} x {cols:,} points, more than {MAX_TERRAIN_POINTS:,}: a shorter or "
                         "narrower strip, or larger cells")  # fmt: skip
    return -before + cell * np.arange(cols), -0.5 * (rows - 1) * cell + cell * np.arange(rows)


def _terrain(heights_x: np.ndarray, xs: np.ndarray, ys: np.ndarray, cell: float, what: str) -> Terrain:
    heights = np.broadcast_to(heights_x, (len(ys), len(xs)))
    return check_terrain(heights.copy(), cell, np.array([xs[0], ys[0]]), what)


def _draw(value: float | None, bounds: tuple[float, float], rng: np.random.Generator, name: str) -> float:
    if value is None:
        return float(rng.uniform(*bounds))
    if not bounds[0] - 1e-12 <= abs(value) <= bounds[1] + 1e-12:
        raise ValueError(f"{name} {value} is outside {bounds[0]:g} to {bounds[1]:g}")
    return float(value)


def stairs(direction: str = "up", steps: int = 6, step_height: float | None = None, step_depth: float = 0.3,
           width: float = 2.0, before: float = 1.0, after: float = 1.0, cell: float = 0.05,
           seed: int = 0) -> Terrain:  # fmt: skip
    """A flight of ``steps`` equal steps up or down along +x, the first riser at x = 0.

    Args:
        direction: ``"up"`` or ``"down"``.
        steps: Number of risers.
        step_height: Rise of one step (m), within :data:`STEP_HEIGHT_RANGE`; None: drawn with ``seed``.
        step_depth: Tread of one step (m).
        width, before, after, cell: The strip (see the module docstring).
        seed: Seeds what is drawn.
    """
    if direction not in ("up", "down") or steps < 1 or not step_depth >= cell:
        raise ValueError(f"stairs need direction 'up' or 'down', steps >= 1 and step_depth >= cell, got "
                         f"{direction!r}, {steps}, {step_depth}")  # fmt: skip
    rise = _draw(step_height, STEP_HEIGHT_RANGE, np.random.default_rng(seed), "step_height")
    xs, ys = _grid(steps * step_depth, width, before, after, cell)
    # Node x is on step k where k depths have been passed: the riser lies between the last node before k * depth
    # and the first node at or after it.
    climbed = np.clip(np.floor(xs / step_depth + 1e-9) + 1, 0, steps)
    sign = 1.0 if direction == "up" else -1.0
    return _terrain(sign * rise * climbed, xs, ys, cell, f"stairs {direction}")


def slope(angle_deg: float | None = None, length: float = 3.0, width: float = 2.0, before: float = 1.0,
          after: float = 1.0, cell: float = 0.1, seed: int = 0) -> Terrain:  # fmt: skip
    """A plane rising (angle > 0) or falling (angle < 0) along +x from x = 0 to ``length``.

    Args:
        angle_deg: Inclination (deg), its size within :data:`SLOPE_ANGLE_RANGE`; None: drawn with ``seed``, up or
            down.
        length, width, before, after, cell: The strip (see the module docstring).
        seed: Seeds what is drawn.
    """
    rng = np.random.default_rng(seed)
    angle = _draw(angle_deg, SLOPE_ANGLE_RANGE, rng, "slope angle_deg")
    if angle_deg is None and rng.random() < 0.5:
        angle = -angle
    xs, ys = _grid(length, width, before, after, cell)
    return _terrain(np.tan(np.radians(angle)) * np.clip(xs, 0.0, length), xs, ys, cell, "slope")


def rough(amplitude: float = ROUGH_AMPLITUDE, bump_spacing: float = 0.3, length: float = 4.0, width: float = 2.0,
          before: float = 1.0, after: float = 1.0, cell: float = 0.1, seed: int = 0) -> Terrain:  # fmt: skip
    """Rough ground: random bumps every ``bump_spacing`` metres, smooth between them, within +-``amplitude``.

    Heights are drawn uniformly in [-amplitude, amplitude] on a coarse grid and interpolated linearly to the cells;
    the ground eases from 0 to full roughness over the first and last ``bump_spacing`` of the feature.

    Args:
        amplitude: Largest bump (m), at most :data:`ROUGH_AMPLITUDE` * 2.
        bump_spacing: Distance between bump centres (m).
        length, width, before, after, cell: The strip (see the module docstring).
        seed: Seeds the bumps.
    """
    if not (0 < amplitude <= 2 * ROUGH_AMPLITUDE and bump_spacing >= cell):
        raise ValueError(f"rough ground needs 0 < amplitude <= {2 * ROUGH_AMPLITUDE} and bump_spacing >= cell, got "
                         f"{amplitude}, {bump_spacing}")  # fmt: skip
    xs, ys = _grid(length, width, before, after, cell)
    rng = np.random.default_rng(seed)
    cx = np.arange(0.0, length + bump_spacing, bump_spacing)
    cy = ys[0] + np.arange(0.0, ys[-1] - ys[0] + bump_spacing, bump_spacing)
    coarse = rng.uniform(-amplitude, amplitude, (len(cy), len(cx)))
    along_x = np.stack([np.interp(xs, cx, row) for row in coarse])  # (len(cy), cols)
    heights = np.stack([np.interp(ys, cy, along_x[:, j]) for j in range(len(xs))], axis=1)
    ease = np.clip(np.minimum(xs, length - xs) / bump_spacing, 0.0, 1.0)
    return check_terrain(heights * ease, cell, np.array([xs[0], ys[0]]), "rough ground")


def boxes(count: int = 4, height_range: tuple[float, float] = BOX_HEIGHT_RANGE,
          size_range: tuple[float, float] = BOX_SIZE_RANGE, length: float = 4.0, width: float = 2.0,
          before: float = 1.0, after: float = 1.0, cell: float = 0.05, seed: int = 0) -> Terrain:  # fmt: skip
    """Flat ground with ``count`` axis-aligned boxes to step on, placed at random over the feature.

    Where boxes overlap the ground takes the higher one.

    Args:
        count: Number of boxes.
        height_range: Range of their heights (m), within :data:`BOX_HEIGHT_RANGE`.
        size_range: Range of their sides (m).
        length, width, before, after, cell: The strip (see the module docstring).
        seed: Seeds the boxes.
    """
    lo, hi = height_range
    if count < 1 or not (BOX_HEIGHT_RANGE[0] <= lo <= hi <= BOX_HEIGHT_RANGE[1]) or not 0 < size_range[0] <= \
            size_range[1]:  # fmt: skip
        raise ValueError(f"boxes need count >= 1, heights within {BOX_HEIGHT_RANGE} and 0 < sizes, got {count}, "
                         f"{height_range}, {size_range}")  # fmt: skip
    xs, ys = _grid(length, width, before, after, cell)
    rng = np.random.default_rng(seed)
    heights = np.zeros((len(ys), len(xs)))
    for _ in range(count):
        sx, sy = rng.uniform(*size_range, size=2)
        x0 = rng.uniform(0.0, max(length - sx, 0.0))
        y0 = rng.uniform(ys[0], max(ys[-1] - sy, ys[0]))
        top = rng.uniform(lo, hi)
        inside = ((xs >= x0) & (xs <= x0 + sx))[None, :] & ((ys >= y0) & (ys <= y0 + sy))[:, None]
        heights = np.where(inside, np.maximum(heights, top), heights)
    return check_terrain(heights, cell, np.array([xs[0], ys[0]]), "boxes")


KINDS = {"stairs": stairs, "slope": slope, "rough": rough, "boxes": boxes}
MAX_COUNT = 1000  # the most steps or boxes a command may ask for
"""The generator's kinds by name (``mimic-motions fit-terrain --terrain KIND``)."""


def parameters(kind: str) -> dict[str, object]:
    """A kind's parameters (but ``seed``) and their defaults (None: drawn with the seed)."""
    import inspect

    return {name: p.default for name, p in inspect.signature(KINDS[kind]).parameters.items() if name != "seed"}


def generate(kind: str, seed: int = 0, settings: list[str] | tuple[str, ...] = ()) -> Terrain:
    """A terrain of ``kind`` from ``NAME=VALUE`` settings of its parameters, as text (the command line's form).

    A value is read as its parameter's default is typed: a number (float, or int for ``steps`` and ``count``), a word
    (``direction=down``), or numbers separated by commas for a range (``height_range=0.05,0.1``); a parameter whose
    default is None (drawn with the seed) takes a number.

    Raises:
        ValueError: an unknown kind or parameter, a value that does not parse, or one the generator refuses (out of
            its documented range), on one line.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown terrain kind {kind!r}; the generator's kinds are {', '.join(KINDS)}")
    defaults = parameters(kind)
    kwargs: dict[str, object] = {}
    for text in settings:
        name, eq, value = text.partition("=")
        name = name.strip()
        if not eq or name not in defaults:
            raise ValueError(f"{kind}: {text!r} is not NAME=VALUE for one of its parameters "
                             f"({', '.join(defaults)})")  # fmt: skip
        if name in kwargs:
            raise ValueError(f"{kind}: parameter {name} given twice")
        default = defaults[name]
        try:
            if isinstance(default, str):
                parsed: object = value.strip()
            elif isinstance(default, tuple):
                parsed = tuple(float(v) for v in value.split(","))
                if len(parsed) != len(default):
                    raise ValueError(f"{len(default)} numbers separated by commas")
            elif isinstance(default, int) and not isinstance(default, bool):
                parsed = int(value)
            else:
                parsed = float(value)
        except ValueError as e:
            what = str(e) if "commas" in str(e) else "an integer" if isinstance(default, int) else "a number"
            raise ValueError(f"{kind}: {name}={value!r} is not {what}") from None
        numbers = parsed if isinstance(parsed, tuple) else (parsed,) if isinstance(parsed, float) else ()
        if not np.isfinite(numbers).all():
            raise ValueError(f"{kind}: {name}={value!r} is not finite")
        if isinstance(parsed, int) and not 0 <= parsed <= MAX_COUNT:  # steps, count: a loop runs over them
            raise ValueError(f"{kind}: {name}={parsed} is outside 0 to {MAX_COUNT:,}")
        kwargs[name] = parsed
    try:
        return KINDS[kind](seed=seed, **kwargs)
    except ValueError as e:
        raise ValueError(f"{kind}: {e}") from None
