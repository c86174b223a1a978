"""One walk along a column from an inclusion towards one end of the insert (:class:`Trace`): the pillar's
cross-section per slab, and where the walk meets the base's surface, read from the ring levels' profile
(:func:`_base_crossing`, :func:`_profile_crossing`), or under a short post clear of its inclusion's ball
(:func:`_clear_end`). The method as a whole: :mod:`lesscli.mri.pillar`."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from lesscli.mri.column import (
    HALF,
    SCALE_EPS,
    _ball_axis,
    _clear_of_ball,
    _Column,
    _column,
    _crossing,
    _from_line,
    _ring_level,
    _slab,
)
from lesscli.robust import MAD_TO_SIGMA

MIN_RADIUS_MM = 0.5             # thinner posts are not told apart from noise
NOISE_Z = 3.0                   # median cross-section over its standard error
MEDIAN_SE = 1.2533              # standard error of a median / (sigma / sqrt(n)) for normal scatter
BASE_PLATEAU_SLABS = 3          # from this many slabs in the base, its level is their mean past the first
PROFILE_GEL_SLABS = 4           # the base surface's profile fit reads this many hydrogel slabs before it
PROFILE_AIR_SLABS = 2           # ... and this many slabs past the insert beyond the base
PROFILE_BLUR_SLABS = (0.2, 2.0)  # ... with its blur within this range, in slabs
# ... moving the half-way crossing by less than this (at it: the crossing kept)
PROFILE_MOVE_SLABS = 0.5
PROFILE_SPARE_SLABS = 2         # ... from this many slabs more than it has unknowns
# the annulus clear of a ball where the base's profile is read under a short post
CLEAR_RING_MM = 4.0
# from this many slabs, a trace's cross-section is tested against their scatter
TESTED_SLABS = 3


@dataclass
class Trace:
    """Slabs beyond one side of an inclusion, up to the base surface.

    Attributes:
        t_mm: (n,) slab centres, mm from the inclusion centre along the traced direction.
        area_mm2: (n,) excess silicone cross-section per slab.
        centroid_mm: (n, 2) lateral position of the excess per slab.
        end_mm: the base surface (where the ring turns silicone or leaves the insert).
        ring: (n,) the ring's (hydrogel) level per slab.
        profiled: where the trace ended in the base: whether the base's profile fit placed ``end_mm``
            (False: the half-way crossing of the ring levels, too few slabs decided that fit;
            :func:`_base_crossing`); None where it ended elsewhere.
    """

    t_mm: np.ndarray
    area_mm2: np.ndarray
    centroid_mm: np.ndarray
    end_mm: float
    ring: np.ndarray
    profiled: bool | None = None

    def median_area(self) -> float:
        return float(np.median(self.area_mm2)) if len(self.area_mm2) else 0.0

    def tested(self) -> bool:
        """Enough slabs (TESTED_SLABS) for their scatter to test the median cross-section against."""
        return len(self.area_mm2) >= TESTED_SLABS

    def deviations(self) -> np.ndarray:
        """The slabs' cross-sections' absolute deviations from their median, the median's own slab (a zero)
        left out where the slabs are odd in number; none where not :meth:`tested`."""
        if not self.tested():
            return np.zeros(0)
        return np.sort(np.abs(self.area_mm2 - self.median_area()))[len(self.area_mm2) % 2:]

    def significant(self, scatter: float | None) -> bool:
        """The median cross-section is a post, not noise: NOISE_Z standard errors of the slab-to-slab
        ``scatter`` (:func:`_pooled_scatter` over the traces that include this one; None only where none
        is :meth:`tested`, this one neither: its median alone decides)."""
        med = self.median_area()
        if med < math.pi * MIN_RADIUS_MM ** 2:
            return False
        if not self.tested():
            return True
        return med >= NOISE_Z * MEDIAN_SE * scatter / math.sqrt(len(self.area_mm2))


def _pooled_scatter(traces) -> float | None:
    """The slab-to-slab scatter of cross-sections (robust standard deviation) over all ``traces`` (measured
    in one core's size) that are :meth:`Trace.tested`, each about its own median; None where none is."""
    dev = np.concatenate([np.zeros(0)] + [t.deviations() for t in traces])
    return MAD_TO_SIGMA * float(np.median(dev)) if len(dev) else None


def _trace(col: _Column, sign: int, line: np.ndarray, core_mm: float, ring_mm: tuple[float, float],
           step_mm: float, voxel_mm3: float, contrast: tuple[float, float], ball=None) -> Trace:
    """Slab profile beyond the inclusion on side ``sign``, around ``line`` = (offset (2,), slope (2,)).

    ``contrast`` = (local hydrogel level, local silicone - hydrogel) of the fraction image. ``ball``: the
    inclusion's fitted blurred ball (:class:`lesscli.mri.ball.Ball`), whose silicone is taken out
    of every slab first; None leaves the slabs as read.
    """
    value = _clear_of_ball(col, ball)
    half = contrast[0] + HALF * contrast[1]
    st = sign * col.t
    slab = _slab(col, sign, st, step_mm) - 1            # slab k centred k + 1 steps out
    beyond = slab >= 0
    rho = _from_line(col.uv, line, st)
    core, ring = rho <= core_mm, (rho > ring_mm[0]) & (rho <= ring_mm[1])
    ts, areas, cents = [], [], []
    levels, cover, ring_ts = [], [], []
    last = int(slab[beyond].max()) if beyond.any() else -1
    for k in range(last + 1):
        here = beyond & (slab == k)
        ring_here = here & ring
        ring_free = ring_here & col.free
        if not ring_here.any() or not ring_free.any():
            break
        level = _ring_level(value[ring_free])
        cover.append(float(col.inside[ring_here].mean()))
        levels.append(level)
        ts.append(float(st[here].mean()))
        ring_ts.append(float(np.median(st[ring_free])))
        if level > half or cover[-1] < HALF:
            break
        sel = here & core & col.free
        excess = value[sel] - level
        scale = max(contrast[0] + contrast[1] - level, SCALE_EPS)     # silicone over this slab's hydrogel
        areas.append(float(excess.sum()) * voxel_mm3 / step_mm / scale)
        w = np.clip(excess, 0.0, None)
        cents.append((w @ col.uv[sel]) / w.sum() if w.sum() > 0 else np.full(2, np.nan))
    n, profiled = len(areas), None
    if not ts:
        end = col.start[sign]
    elif levels[-1] > half:
        end, n, profiled = _base_crossing(col, st, slab, ring, ring_ts, levels, contrast, last, step_mm)
        n = min(n, len(areas))
    elif cover[-1] < HALF:
        end = _crossing(np.asarray(ts), 1.0 - np.asarray(cover), len(ts) - 1)
    else:
        end = ts[-1] + 0.5 * step_mm
    return Trace(np.asarray(ts[:n]), np.asarray(areas[:n]), np.asarray(cents[:n]).reshape(n, 2), end,
                 np.asarray(levels[:n]), profiled)


def _base_crossing(col: _Column, st: np.ndarray, slab: np.ndarray, ring: np.ndarray, ts: list, levels: list,
                   contrast: tuple[float, float], last: int, step_mm: float) -> tuple[float, int, bool]:
    """(base surface t, slabs before it, whether the profile fit placed it) from the ring levels ``levels``
    of the slabs at ``ts`` (the last one in the base): fitted to them and to the ring levels of the slabs
    past them, through the base and PROFILE_AIR_SLABS slabs past the insert (:func:`_profile_crossing`,
    the hydrogel level fitted too from two slabs before the base on); where too few slabs decide that
    fit, where the levels cross half-way between the hydrogel and the base's own level.

    That level is read from the medians over the ring's voxels away from the insert's outer surface
    in the slabs from the last one on, as long as the ring has such voxels: their mean past the first
    (from BASE_PLATEAU_SLABS slabs on), else the highest (noise biases it up), else the inclusion's.
    Where the first slab already lies in the base, the crossing is found between the inclusion's last
    slice and that slab.
    """
    base = []
    for k in range(len(ts) - 1, last + 1):
        deep = (slab == k) & ring & col.free & col.deep
        if not deep.any():
            break
        base.append(_ring_level(col.value[deep]))
    if len(base) >= BASE_PLATEAU_SLABS:
        plateau = float(np.mean(base[1:]))
    else:
        plateau = max(base) if base else contrast[0] + contrast[1]
    scale = max(plateau - contrast[0], SCALE_EPS)
    norm = (np.asarray(levels) - contrast[0]) / scale
    j = int(np.argmax(norm > HALF)) if (norm > HALF).any() else len(ts) - 1
    t, norm = np.asarray(ts[:j + 1]), norm[:j + 1]
    before_t, before = (list(ts[max(j - PROFILE_GEL_SLABS, 0):j]),
                        list(levels[max(j - PROFILE_GEL_SLABS, 0):j]))
    inclusion_side = (slab == -1) & ring & col.free          # the inclusion's last slice
    if j == 0 and inclusion_side.any():
        before_t, before = [float(np.median(st[inclusion_side]))], [_ring_level(col.value[inclusion_side])]
        t = np.array(before_t + [ts[0]])
        norm = np.array([(before[0] - contrast[0]) / scale, norm[0]])
    linear = _crossing(t, norm, len(t) - 1)
    after_t, after, air = list(ts[j:]), list(levels[j:]), []
    for k in range(len(ts), last):      # through the base and into what lies beyond it (not the crop's edge)
        sel = (slab == k) & ring & ~(col.inside & ~col.free)
        if not sel.any() or len(air) >= PROFILE_AIR_SLABS:
            break
        after_t.append(float(np.median(st[sel])))
        after.append(_ring_level(col.value[sel]))
        if float(col.inside[(slab == k) & ring].mean()) < HALF:
            air.append(after_t[-1])
    fitted = _profile_crossing(np.asarray(before_t + after_t), np.asarray(before + after),
                               None if len(before) >= 2 else contrast[0], linear, step_mm,
                               air[0] - 0.5 * step_mm if air else None)
    return (linear if fitted is None else fitted), j, fitted is not None


def _slab_step(x: np.ndarray, sigma: float, width: float) -> np.ndarray:
    """A unit step at 0 blurred by a Gaussian of ``sigma`` and averaged over slabs of ``width`` (the box
    partial volume) centred at ``x``: 0 far before it, 1 far past it."""
    from scipy.special import ndtr

    def g(z):
        return z * ndtr(z) + np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)

    return (g((x + 0.5 * width) / sigma) - g((x - 0.5 * width) / sigma)) * sigma / width


def _profile_crossing(t: np.ndarray, v: np.ndarray, hydrogel: float | None, start: float, step_mm: float,
                      beyond: float | None) -> float | None:
    """The base surface along a column, fitted to the ring levels ``v`` of the slabs at ``t`` (hydrogel
    before it, then the base and, where ``beyond`` (where the insert ends past the base, roughly) is
    given, what lies past the base: air, a container): each slab the mean over its width of the profile
    hydrogel -> base -> beyond blurred by one Gaussian; the three levels (the hydrogel's given as
    ``hydrogel`` where the slabs before the base are too few for it), both surfaces and the blur fitted.
    None where too few slabs decide them or the base reads no brighter than the hydrogel in silicone.

    A base of 3 mm in slabs of about a millimetre shows no plateau of its own: the blur of what lies
    beyond it moves every slab in it, up where that reads above the silicone (air when the silicone is
    the darker tissue) and down where below, so a level read in the base misplaces a crossing half-way to
    it; and a linear crossing between two slabs of a blurred boxed step errs by up to a tenth of a slab,
    depending on where the surface falls within a slab. ``start``: the linear crossing, from which the
    surface moves by less than PROFILE_MOVE_SLABS slabs (a fit that reaches that is not taken: a base of
    two or three slabs leaves its level, its blur and both its surfaces free to trade)."""
    from scipy.optimize import least_squares

    unknowns = (2 if beyond is None else 3) + (1 if beyond is None else 2) + (hydrogel is None)
    if len(t) < unknowns + PROFILE_SPARE_SLABS or step_mm <= 0:
        return None

    def levels(p):
        a = _slab_step(t - p[0], math.exp(p[-1]), step_mm)
        b = _slab_step(t - p[1], math.exp(p[-1]), step_mm) if beyond is not None else np.zeros_like(t)
        columns = [a - b] + ([b] if beyond is not None else []) + ([1.0 - a] if hydrogel is None else [])
        design = np.column_stack(columns)
        target = v if hydrogel is None else v - hydrogel * (1.0 - a)
        coef = np.linalg.lstsq(design, target, rcond=None)[0]
        base_over_gel = coef[0] - (coef[-1] if hydrogel is None else hydrogel)
        return design @ coef - target, base_over_gel

    blur = [math.log(f * step_mm) for f in PROFILE_BLUR_SLABS]
    reach = PROFILE_MOVE_SLABS * step_mm
    if beyond is None:
        x0, lo, hi = [start, math.log(0.5 * step_mm)], [start - reach, blur[0]], [start + reach, blur[1]]
    else:
        far = float(t[-1]) + step_mm
        x0 = [start, min(max(beyond, start + step_mm), far - 1e-3), math.log(0.5 * step_mm)]
        lo, hi = [start - reach, start, blur[0]], [start + reach, far, blur[1]]
    fit = least_squares(lambda p: levels(p)[0], x0, bounds=(lo, hi))
    at_bound = abs(fit.x[0] - start) > 0.99 * reach
    if not fit.success or at_bound or levels(fit.x)[1] <= SCALE_EPS:
        return None
    return float(fit.x[0])


def _clear_radius(ball, voxel_mm: float) -> float:
    """How far from a fitted ball's axis its blurred silicone (two sigmas of the blur) and a voxel reach."""
    return ball.radius_mm + 2.0 * ball.sigma_mm + voxel_mm


def _clear_end(fraction, insert, deep, inc_ids, label: int, centres: np.ndarray, balls: dict,
               axis: np.ndarray, spacing: np.ndarray, side: int, step_mm: float, voxel_mm3: float,
               contrast: tuple[float, float]) -> float | None:
    """The base surface under inclusion ``label`` (mm along ``side`` * ``axis`` from its body's centre, as
    :attr:`Trace.end_mm`) read in an annulus CLEAR_RING_MM wide around its fitted ball's axis, clear of the
    ball's blur (:func:`_clear_radius`) and of every other inclusion's, walked from up to PROFILE_GEL_SLABS +
    2 slabs beside the ball (not past its centre): the hydrogel before the base is read there, and the base's
    profile fitted (:func:`_base_crossing`). None without a fitted ball or where that fit is not decided
    either.

    Under a post a slab or two tall the ring of the post's own trace holds a slab or two of hydrogel, whose
    levels the ball's blur raises: too few for the profile fit, and the half-way crossing that stands in
    for it was 0.27 mm short under a 1.5 mm post in 1.19 mm slices without noise (seed 5086 of the family).
    """
    ball = balls[label]
    if ball is None:
        return None
    voxel = float(spacing.max())
    centre = centres[label - 1]
    line = _ball_axis(ball, centre, axis)
    inner = _clear_radius(ball, voxel)
    col = _column(fraction, insert, deep, inc_ids, label, centre, axis, spacing,
                  inner + CLEAR_RING_MM + float(np.linalg.norm(line[0])))
    others = [fitted for other, fitted in balls.items() if other != label]
    if None in others:
        return None
    near_other = np.zeros(len(col.t), dtype=bool)
    for other in others:
        near_other |= (_from_line(col.uv, _ball_axis(other, centre, axis), col.t)
                       <= _clear_radius(other, voxel))
    back = min(PROFILE_GEL_SLABS + 2, math.floor(col.start[side] / step_mm))
    col = replace(col, free=col.free & ~near_other,
                  start={**col.start, side: col.start[side] - back * step_mm})
    trace = _trace(col, side, line, inner, (inner, inner + CLEAR_RING_MM), step_mm, voxel_mm3, contrast)
    return trace.end_mm if trace.profiled else None


def _contrast(fraction: np.ndarray, inc_ids: np.ndarray, label: int, col: _Column, ring_mm,
              spacing) -> tuple[float, float]:
    """(hydrogel level, silicone - hydrogel): the inclusion's interior against the column's ring."""
    from scipy import ndimage

    sl = ndimage.find_objects(inc_ids, max_label=label)[label - 1]
    own = np.pad(inc_ids[sl] == label, 1)
    depth = ndimage.distance_transform_edt(own, sampling=spacing)[1:-1, 1:-1, 1:-1]
    interior = ((depth > float(spacing.max())) if (depth > float(spacing.max())).any()
                else own[1:-1, 1:-1, 1:-1])
    silicone = float(np.median(fraction[sl][interior]))
    rho = _from_line(col.uv)
    ring = col.free & (rho > ring_mm[0]) & (rho <= ring_mm[1])
    hydrogel = _ring_level(col.value[ring]) if ring.any() else 0.0
    return hydrogel, max(silicone - hydrogel, SCALE_EPS)


def _walked_contrast(both: list[Trace], contrast: tuple[float, float]) -> tuple[float, float]:
    """``contrast`` with the hydrogel level re-read as the median ring level of the slabs walked.

    The column's ring also passes through the skin and the base, which pulls its median towards
    silicone as noise widens both levels; the slabs walked stop short of them.
    """
    rings = np.concatenate([t.ring for t in both])
    if not len(rings):
        return contrast
    hydrogel = float(np.median(rings))
    return hydrogel, max(contrast[0] + contrast[1] - hydrogel, SCALE_EPS)
