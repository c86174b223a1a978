"""The column of a pillar's search: the insert's voxels around the line along the insert axis through one
inclusion, in the frame a pillar is traced in (``st`` from the inclusion's centre, ``uv`` across the axis),
its slabs and rings, and the ring's robust level; the ball fitted to an inclusion, seen from the column."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lesscli.robust import robust_sigma

HALF = 0.5                      # ring level / insert coverage at the base surface
OUTLIER_SIGMAS = 3.0            # a ring's voxels further than this from its median are other structures
RING_LEVEL_ROUNDS = 5           # ... median and spread taken again over the rest, at most this often
SCALE_EPS = 1e-3


@dataclass
class _Column:
    """Insert voxels near the line through one inclusion (flat arrays over the selected voxels)."""

    index: tuple[np.ndarray, ...]
    t: np.ndarray                   # mm along the axis from the inclusion centre
    uv: np.ndarray                  # (n, 2) lateral mm
    value: np.ndarray               # silicone fraction
    inside: np.ndarray              # in the insert
    free: np.ndarray                # in the insert and in no inclusion
    deep: np.ndarray                # in the insert, away from its outer surface (partial volume with air)
    other: np.ndarray               # in another inclusion
    points: np.ndarray              # (n, 3) array-axis mm
    start: dict                     # direction sign -> t of the inclusion's surface along it


def _basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ref = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = ref - (ref @ axis) * axis
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def _from_line(uv: np.ndarray, line: np.ndarray | None = None, st: np.ndarray | None = None) -> np.ndarray:
    """Each point's distance (mm) from ``line`` = (lateral offset (2,), slope (2,) along ``st``, the points'
    distance along the axis towards the side walked) in the lateral positions ``uv`` (n, 2) of a column;
    None: from the column's centre line."""
    return np.linalg.norm(uv if line is None else uv - line[0] - st[:, None] * line[1], axis=1)


def _column(fraction, insert, deep, inc_ids, label, centre_mm, axis, spacing, reach_mm) -> _Column:
    grids = [np.arange(n, dtype=np.float32) * np.float32(s) - np.float32(c)
             for n, s, c in zip(fraction.shape, spacing, centre_mm)]
    d = np.meshgrid(*grids, indexing="ij", sparse=True)
    t = d[0] * np.float32(axis[0]) + d[1] * np.float32(axis[1]) + d[2] * np.float32(axis[2])
    r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] - t * t
    index = np.nonzero(r2 <= reach_mm ** 2)
    offsets = np.stack([d[k].ravel()[index[k]] for k in range(3)], axis=1).astype(np.float64)
    e1, e2 = _basis(axis)
    ids = inc_ids[index]
    t_sel = t[index].astype(np.float64)
    own = ids == label
    start = {sign: float((sign * t_sel[own]).max()) if own.any() else 0.0 for sign in (1, -1)}
    inside = insert[index]
    return _Column(index, t_sel, np.stack([offsets @ e1, offsets @ e2], axis=1),
                   fraction[index].astype(np.float64), inside, inside & (ids == 0), deep[index],
                   (ids != 0) & ~own, offsets + np.asarray(centre_mm), start)


def _slab(col: _Column, sign: int, st, step_mm: float) -> np.ndarray:
    """Slab index of depth ``st`` (mm beyond the inclusion on side ``sign``): slabs ``step_mm`` thick centred
    on the column's planes of voxel centres (slab 0 on ``col.start[sign]``, a voxel's). A slab's edge on a
    plane would split that slice's voxels between two slabs by the axis's slightest tilt (or by rounding), and
    read
    each slab's ring level between two slices."""
    return np.floor((np.asarray(st) - col.start[sign]) / step_mm + 0.5).astype(np.int64)


def _clear_of_ball(col: _Column, ball) -> np.ndarray:
    """The column's values with the inclusion's blurred ball (:class:`lesscli.mri.ball.Ball`) taken
    out; None leaves them as read."""
    return col.value if ball is None else col.value - ball.excess(col.points)


def _ball_surface(ball, centre_mm: np.ndarray, axis: np.ndarray, sign: int) -> float:
    """Where the inclusion's fitted ball ends on side ``sign``, in mm along ``axis`` from ``centre_mm``."""
    return sign * float((ball.centre_mm - centre_mm) @ axis) + ball.radius_mm


def _ball_axis(ball, centre_mm: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The line (lateral offset, slope) along ``axis`` through the fitted ball's centre, in the frame of
    the column around ``centre_mm``; without a ball (None), through ``centre_mm`` (the body's)."""
    if ball is None:
        return np.zeros((2, 2))
    e1, e2 = _basis(axis)
    d = ball.centre_mm - centre_mm
    return np.array([[d @ e1, d @ e2], [0.0, 0.0]])


def _blur_mm(ball, step_mm: float) -> float:
    """The scan's blur: the inclusion's fitted ball's, else half a slab."""
    return ball.sigma_mm if ball is not None else 0.5 * step_mm


def _ring_level(values: np.ndarray) -> float:
    """The level of a ring's voxels: their median, taken again over those within OUTLIER_SIGMAS robust
    standard deviations of it (the spread read again from those too) until none more is left out. A ring
    that passes through the skin beside an inclusion near the insert's wall holds some silicone, which
    moves a plain median up by a fraction of the noise; summed over the few dozen voxels of a core, that
    offset is as large as a thin post's cross-section."""
    kept = values
    for _ in range(RING_LEVEL_ROUNDS):
        level = float(np.median(kept))
        spread = robust_sigma(kept, level)
        if spread <= 0:
            break
        near = np.abs(values - level) <= OUTLIER_SIGMAS * spread
        if near.sum() in (0, len(kept)):
            break
        kept = values[near]
    return float(np.median(kept))


def _crossing(t: np.ndarray, level: np.ndarray, k: int) -> float:
    """Where ``level`` crosses HALF between slab k-1 and slab k (linear), else slab k's centre."""
    if k == 0 or level[k] == level[k - 1]:
        return float(t[k])
    w = (HALF - level[k - 1]) / (level[k] - level[k - 1])
    return float(t[k - 1] + np.clip(w, 0.0, 1.0) * (t[k] - t[k - 1]))


def _own(col: _Column) -> np.ndarray:
    """The column's voxels of its own inclusion's body."""
    return col.inside & ~col.free & ~col.other


def _run_on(col: _Column, side: int, step_mm: float) -> bool:
    """The inclusion's body reaches more than a slab further towards the base than away from it: over a
    post a slab or so tall the opening that finds it keeps the post's slab and some of the base's."""
    return col.start[side] - col.start[-side] > step_mm


def _beyond_ball(col: _Column, sign: int, ball, centre_mm: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The column's voxels of the inclusion's body beyond its fitted ball's surface on side ``sign``."""
    return _own(col) & (sign * col.t > _ball_surface(ball, centre_mm, axis, sign))


def _past_ball(col: _Column, sign: int, ball, centre_mm: np.ndarray, axis: np.ndarray) -> _Column:
    """``col`` with the inclusion's own voxels beyond its fitted ball's surface on side ``sign`` freed
    and its start moved to that surface. Under a pillar a slice or two tall the body can hold the
    pillar's slice, and the gap between it and the base then holds no voxel to measure the post in."""
    surface = _ball_surface(ball, centre_mm, axis, sign)
    if surface >= col.start[sign]:
        return col
    return replace(col, free=col.free | _beyond_ball(col, sign, ball, centre_mm, axis),
                   start={**col.start, sign: surface})
