"""A post's cross-section: from its trace's slabs, fitted to its whole silicone where it is a slab or two
tall (:func:`_post_radius`), across a gap too short to hold a slab (:func:`_gap_radius`), or pooled over the
scan's posts (:func:`_pooled_radii`); and the base's side, from the posts the traces show
(:func:`_base_side`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from lesscli.mri.column import HALF, _blur_mm, _clear_of_ball, _Column, _from_line, _ring_level, _slab
from lesscli.mri.cylinder import disc_profile
from lesscli.mri.trace import MIN_RADIUS_MM, Trace, _pooled_scatter

SHORT_GAP_SLABS = 2.5           # a closer base leaves too few slabs to measure a cross-section
GAP_AXIS_MM = 0.75              # the voxels this close to the line decide whether a short gap holds a post
MIN_OWN_SLABS = 4               # fewer slabs take the cross-section pooled over the scan's pillars
# a significant post this wide (1.4 mm) outweighs a brief side of its inclusion
CLEAR_POST_RADIUS_MM = 0.7


def _inner(trace: Trace) -> Trace:
    """Leave out the slab next to the inclusion and, from 3 slabs, the one next to the base (partial
    volume)."""
    n = len(trace.area_mm2)
    if n < 2:
        return trace
    keep = slice(1, n - 1 if n >= 3 else n)
    return replace(trace, t_mm=trace.t_mm[keep], area_mm2=trace.area_mm2[keep],
                   centroid_mm=trace.centroid_mm[keep], ring=trace.ring[keep])


def _short_gap(trace: Trace, col: _Column, sign: int, step_mm: float) -> bool:
    """The base lies within SHORT_GAP_SLABS slabs of the inclusion: too close for cross-sections."""
    return trace.end_mm - col.start[sign] <= SHORT_GAP_SLABS * step_mm


def _gap_area(col: _Column, sign: int, end_mm: float, contrast: tuple[float, float], core_mm: float,
              step_mm: float, voxel_mm3: float, line: np.ndarray | None = None) -> float | None:
    """Cross-section (mm^2) of the core's silicone across a short gap between an inclusion and the
    base, or None where the gap holds no post: along the line (``line``, :func:`_ball_axis`; None: the
    column's centre) it is hydrogel (the inclusion seen reaching the base counts as silicone; a voxel in
    partial volume with the air past the insert, half silicone, reads as hydrogel and decides nothing)."""
    st = sign * col.t
    gap = col.free & (st > col.start[sign]) & (st <= end_mm)
    rho = _from_line(col.uv, line, st)
    axis_voxels = gap & col.deep & (rho <= GAP_AXIS_MM)
    half = contrast[0] + HALF * contrast[1]
    if axis_voxels.any() and float(np.median(col.value[axis_voxels])) <= half:
        return None
    length = max(end_mm - col.start[sign], step_mm)
    return float((col.value[gap & (rho <= core_mm)] > half).sum()) * voxel_mm3 / length


def _post_radius(col: _Column, sign: int, start_mm: float, end_mm: float, ball, contrast: tuple[float, float],
                 core_mm: float, ring_mm: tuple[float, float], step_mm: float, voxel_mm3: float,
                 line: np.ndarray) -> float:
    """Radius of a short post, from ``start_mm`` (the inclusion's surface) to ``end_mm`` (the base's), fitted
    by least squares to all its silicone: the core's excess over the ring's level (the inclusion's
    blurred ball taken out first, in units of the inclusion's contrast) from the blur's reach (two sigmas
    of the ball's blur) inside the inclusion to as far past the base surface, against a cylinder under the
    post's ``line`` (:func:`_ball_axis`, where it is drawn) blurred like the inclusion (:func:`disc_profile`
    across, a normal's integral along), the core and ring centred on that line.
    The blur carries much of a post a slab or two tall into the inclusion's and the base's slabs, so its
    own slabs read it too thin; the start is the radius of the whole excess over the gap's length. Each
    voxel's excess is over the ring's level at its own depth, read over half-slabs and interpolated (where the
    axis is tilted a slab's voxels spread over its depth, and about the base's surface one level per slab is
    the wrong background for most of them; upright, every voxel lies at a half-slab's depth). The
    post fills the ball's curve: at each voxel's distance from the line it starts at the ball's surface,
    not at the plane through its lowest point (which left the silicone between them, pi r^4 / (4 R), to
    widen the post: by about 0.1 mm in diameter for a 3 mm post 1.5 mm tall under a 10 mm ball).

    The ball's radius is fitted again with the post, within one blur of the one taken out (its
    :meth:`~lesscli.mri.ball.Ball.shell`; the post starts at the surface of the ball so fitted):
    the ball's fit left out the cap over the post, so the cap is where the rest of the ball places it,
    and a hundredth of a millimetre off there, over a core some 3 mm wide, is a post of a millimetre
    squared in a gap half a millimetre tall. Spheres without posts 0.5-1 mm under the skin showed posts
    of 0.50-0.53 mm in their gaps to it (seeds 32, 33, 56 and 97 of the family's ``--near-skin
    --floating``, box partial volume), over MIN_RADIUS_MM; fitted with the ball's radius, 0.25-0.46 mm."""
    from scipy.optimize import least_squares
    from scipy.special import ndtr

    value = _clear_of_ball(col, ball)
    st = sign * col.t
    slab = _slab(col, sign, st, step_mm)
    rho = _from_line(col.uv, line, st)
    core, ring = rho <= core_mm, (rho > ring_mm[0]) & (rho <= ring_mm[1])
    sigma = _blur_mm(ball, step_mm)
    reach = math.ceil(2.0 * sigma / step_mm)
    at, ring_t, ring_level = [], [], []
    first, last = (int(_slab(col, sign, t, step_mm)) for t in (start_mm, end_mm))
    half, ring_free = _slab(col, sign, st, 0.5 * step_mm), ring & col.free
    for k in range(first - reach, last + reach + 1):
        if (ring_free & (slab == k)).any():
            at.append(np.flatnonzero((slab == k) & core & col.inside & ~col.other))
        for h in (2 * k - 1, 2 * k):
            background = ring_free & (half == h)
            if background.any():
                ring_t.append(float(np.median(st[background])))
                ring_level.append(_ring_level(value[background]))
    if not at:
        return 0.0
    at = np.concatenate(at)
    excess = (value[at] - np.interp(st[at], ring_t, ring_level)) / contrast[1]
    def axial(wider: float) -> np.ndarray:
        """The post along its length, from the surface of the ball ``wider`` (mm) than fitted above each
        voxel."""
        top = start_mm if ball is None else start_mm - ball.radius_mm + np.sqrt(np.maximum(
            (ball.radius_mm + wider) ** 2 - rho[at] ** 2, 0.0))
        return ndtr((st[at] - top) / sigma) - ndtr((st[at] - end_mm) / sigma)

    shell = np.zeros(len(at)) if ball is None else ball.shell(col.points[at]) / contrast[1]
    whole = float(excess.sum()) * voxel_mm3 / max(end_mm - start_mm, step_mm)
    start = min(_disc_radius(whole), core_mm)
    fit = least_squares(lambda p: disc_profile(rho[at], p[0], sigma) * axial(p[1]) + p[1] * shell - excess,
                        [max(start, 0.1 * core_mm), 0.0], bounds=([0.05 * core_mm, -sigma], [core_mm, sigma]))
    return float(fit.x[0])


def _gap_radius(col: _Column, sign: int, end_mm: float, contrast: tuple[float, float], core_mm: float,
                step_mm: float, voxel_mm3: float, found: dict, line: np.ndarray, widest_mm: float,
                fitted: Callable[[], float] | None = None) -> float | None:
    """Radius of the post across a short gap between an inclusion and the base along ``line``, or None
    (no post): the median of the scan's measured pillars, else ``fitted()`` (:func:`_post_radius`, given
    where the inclusion's ball was fitted), else that of the core's silicone in the gap; the last two must
    lie between a disc of MIN_RADIUS_MM and one of the widest pillar's radius (``widest_mm`` across: more
    is the base's or the inclusion's silicone, not a post's)."""
    area = _gap_area(col, sign, end_mm, contrast, core_mm, step_mm, voxel_mm3, line)
    if area is None:
        return None
    if found:
        return float(np.median([r for _line, r, _end in found.values()]))
    radius = fitted() if fitted is not None else _disc_radius(area)
    return radius if MIN_RADIUS_MM <= radius <= 0.5 * widest_mm else None


def _base_side(traces: dict, columns: dict, contrasts: dict, labels: list[int], core_mm: float,
               step_mm: float, voxel_mm3: float) -> int:
    """+1 or -1: the side of the inclusions where the base lies, from the excess silicone beyond them.

    In order, the first that decides: the cross-sections summed per side of the significant posts (their
    medians) and of the posts across short gaps to the base (:func:`_gap_area`, at least a disc of
    MIN_RADIUS_MM: the body may reach the base and leave the gap no voxel); the median cross-sections of
    every trace summed per side. A pillar shorter than two slabs leaves no slab to measure, and a short gap
    that holds silicone along the inclusion's axis is where its post is: its other side is not counted. A
    bias field curved across the column raises a wide core over its ring by a millimetre squared or so,
    which a long trace of hydrogel on the skin side then passes as a post. But a side too brief to test
    against the noise (a short gap, or a trace not :meth:`Trace.tested` past the slab next to the
    inclusion) decides nothing against a significant post at least a disc of CLEAR_POST_RADIUS_MM on the
    other side: a sphere a voxel or two under the skin leaves a gap to it that holds no voxel, or one or
    two slabs that the blur of the skin and the sphere fill as a post's silicone would, and taken for its
    post's side, it lost the post under the sphere (a post of 1.5 mm, the thinnest cast, measures about
    2 mm^2 there; the long hydrogel traces beside a short gap, 0.7 mm^2 at most, were not significant).
    """
    inner = {key: _inner(trace) for key, trace in traces.items()}
    scatter = _pooled_scatter(inner.values())
    strong = 0.0
    for k in labels:
        short = [sign for sign in (1, -1) if _short_gap(traces[k, sign], columns[k], sign, step_mm)]
        brief = [sign for sign in (1, -1) if sign in short or not inner[k, sign].tested()]
        clear = [sign for sign in (1, -1) if sign not in brief and inner[k, sign].significant(scatter)
                 and inner[k, sign].median_area() >= math.pi * CLEAR_POST_RADIUS_MM ** 2]
        if len(brief) == 1 and clear == [-brief[0]]:
            strong += clear[0] * inner[k, clear[0]].median_area()
            continue
        gaps = {sign: _gap_area(columns[k], sign, traces[k, sign].end_mm, contrasts[k], core_mm, step_mm,
                                voxel_mm3)
                for sign in short}
        gaps = {sign: max(area, math.pi * MIN_RADIUS_MM ** 2) for sign,
                area in gaps.items() if area is not None}
        strong += sum(sign * area for sign, area in gaps.items()) if gaps else sum(
            sign * inner[k, sign].median_area() for sign in (1, -1) if inner[k, sign].significant(scatter))
    weak = sum(sign * inner[k, sign].median_area() for k in labels for sign in (1, -1))
    for evidence in (strong, weak):
        if evidence:
            return 1 if evidence > 0 else -1
    return 1


def _disc_radius(area_mm2: float) -> float:
    """The radius (mm) of a disc of ``area_mm2``; 0 where that is not positive (a cross-section of noise)."""
    return math.sqrt(max(area_mm2, 0.0) / math.pi)


def _pooled_radii(found: dict, short_radius: Callable[[int, float, float], float]) -> dict:
    """label -> (line, radius, end) from label -> (line, slab cross-sections, core radius, end).

    A pillar measured over at least MIN_OWN_SLABS slabs keeps the median of its own cross-sections; a
    shorter one has its radius fitted to all its silicone (``short_radius(label, core, end)``,
    :func:`_post_radius`) and, where that shows a post (MIN_RADIUS_MM), takes the median over the slabs
    of the scan's pillars measured over MIN_OWN_SLABS slabs or more, else, with other short posts that
    show one, the median of their fitted radii. Its own few slabs, read with the ball as fitted without
    the cap over them, passed a sphere's gap to the skin as a post: two spheres without posts 1.4 and
    2.6 mm under the skin drew posts of 0.71 mm there (seed 51 of the family's ``--near-skin
    --floating``, box partial volume); so fitted, 0.45 and 0.13 mm. Nor are a short post's slabs pooled:
    the blur carries much of it into its inclusion's and the base's slabs (:func:`_post_radius`), and
    where every post of a scan was short, the median of their slabs drew them too thin (the family's
    volumes whose two or three posts are all short, in seeds 0-6099 and 7000-7149, box partial volume:
    all six drawn narrow, by 0.09 mm in diameter on average, five of them from their slabs). The radius
    never exceeds the core it was measured in.
    """
    fitted = {label: short_radius(label, core, end) for label, (_line, areas, core, end) in found.items()
              if len(areas) < MIN_OWN_SLABS}
    pooled = np.concatenate([np.zeros(0)] + [areas for _line, areas, _core, _end in found.values()
                                             if len(areas) >= MIN_OWN_SLABS])
    shown = [radius for radius in fitted.values() if radius >= MIN_RADIUS_MM]
    out = {}
    for label, (line, areas, core, end) in found.items():
        if len(areas) >= MIN_OWN_SLABS:
            radius = _disc_radius(float(np.median(areas)))
        elif fitted[label] < MIN_RADIUS_MM:
            radius = fitted[label]
        else:
            radius = _disc_radius(float(np.median(pooled))) if len(pooled) else float(np.median(shown))
        out[label] = (line, min(radius, core), end)
    return out
