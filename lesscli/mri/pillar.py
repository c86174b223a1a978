"""Pillars: the thin silicone post between each inclusion and the base, traced along the insert axis.

Nothing here assumes a pillar's diameter, intensity or which end of the insert the base is at. For
each inclusion, the insert's voxels near the line through its centre along the insert axis are cut
into slabs one plane of voxel centres thick, on both sides of the inclusion, each centred on a plane of
voxel centres one step further from the inclusion (where the insert axis is an array axis, a slab is one
slice; boundaries through voxel centres would split each slice between two slabs; along a tilted axis the
planes normal to the array axis nearest it lie that axis's spacing over the tilt's cosine apart, and a slab
as thick holds one of them wherever the tilt keeps them apart across the ring). Per slab
(``fraction``: 0 hydrogel, 1 silicone):

- the ring (an annulus around the core) gives the local background: hydrogel between the inclusion
  and the base, silicone once the ring enters the base or the skin (its level a median clipped of the
  voxels far from it, :func:`_ring_level`, so that the skin of a nearby wall, in part of the ring, does
  not raise it). The trace ends there, or where
  the ring leaves the insert (a pillar standing on the insert's outer surface): that is the base
  surface, fitted to the ring levels of a few slabs of hydrogel, the base and two slabs past the
  insert (:func:`_profile_crossing`: a thin base has no level of its own, the blur of the air beyond
  it moves every slab), from the crossing half-way between the hydrogel and the base's level read in
  it (:func:`_base_crossing`). Where too few slabs decide that fit (a post a slab or two tall), the
  profile is read in an annulus clear of the inclusion's fitted ball (:func:`_clear_end`), and the
  half-way crossing stands only where that does not decide it either;
- the core's silicone in excess of the ring level, summed over the slab and divided by the contrast
  of the inclusion's interior over that ring level, is the pillar's cross-section (mm^2). A sum is
  unchanged by partial volume and blur, so a pillar 1-2 voxels wide is measured as well as a wide one,
  and no intensity threshold is involved. Next to an inclusion the blur also spreads the sphere's own
  silicone beyond its surface, most of it along the line under its centre, where the pillar stands:
  in the pillar's trace, the inclusion's blurred ball (centre, radius, blur and contrast fitted to its
  profile away from the pillar's column, :func:`lesscli.mri.morphology.fitted_ball`) is taken out of
  every voxel first (under a small inclusion the cap reached a slab or two beyond its surface);
- the weighted centroid of the excess locates the pillar in the slab.

The hydrogel level that places the half-way crossing is the median ring level of the slabs walked on
either side (a ring over the whole column would also take in the skin and the base).

The base is on the side where the inclusions together show more excess silicone (on the skin side
there is none): the cross-sections of the significant posts and of the posts across short gaps to the base
(a gap that holds silicone is where its inclusion's post is) decide, else every trace's median
cross-section (:func:`_base_side`). An inclusion found reaching
past its fitted blurred ball towards the base holds pillar there (under a pillar a slice or two tall
the opening keeps the pillar's slice); those voxels are the trace's from then on. On that side an
inclusion has a pillar when the median cross-section exceeds a disc of ``MIN_RADIUS_MM`` and
``NOISE_Z`` standard errors of the slab-to-slab scatter, read over all the scan's traces each about its
own median (:func:`_pooled_scatter`: a post's own three or four slabs read it too poorly to test
against), in the first core (the widest pillar's radius and a margin) or else in one of half that
radius and the same margin, whose fewer voxels of noise let a thin post in strong noise pass (each
core against its own traces' scatter; a trace of noise alone may pass either, at most twice as often
as one). The pillar is then the cylinder of the measured area from the inclusion down to the base
surface, around the straight line fitted to the slab centroids of a second trace (a core fitted to
the pillar, so less noise in the centroids). That line and radius start a least-squares fit of a straight blurred cylinder
(:func:`disc_profile`) to the second trace's voxels, which gives the pillar drawn: a post
two voxels wide shows a few noisy voxels per slab, whose weighted centroids placed it up to half a
voxel off, and at that width half a voxel decides about a third of its voxels. The cylinder's blur is
fitted with it (:func:`fit_blurred_cylinder`), from the inclusion's: the blur across a post is the
scan's across the insert axis, which a ball's one blur, averaged over all directions, misreads where
the slices are thicker or thinner than the in-plane voxels (and with it the radius). The post is then
held on its inclusion's axis (the line through the fitted ball's centre along the insert axis, as the
phantoms are cast) unless a line of its own fits significantly better, one along the insert axis first and
a tilted one only past that, the tests reading the noise as the denoising correlated it (:func:`own_or_centred`). A post measured
thinner than ``MIN_RADIUS_MM`` in the end is no post (its first, wider core let noise pass the test;
without posts, about one inclusion in ten of the family's had one, drawn with a voxel or none and with
its warning missing), by its fitted cylinder or by its second trace's median cross-section: a trace of
noise 17 mm long under a sphere near the skin read a disc of 0.26 mm there and a cylinder over 0.5 mm,
the fit's blur and radius trading against each other on a few voxels per slab. Short pillars are
measured over few slabs, each as noisy as the next:

- with fewer than ``MIN_LINE_SLABS`` slabs a line is not told apart from noise, and the pillar stands
  under its inclusion's centre, as the phantoms are built (one pillar under each sphere's centre,
  :func:`lesscli.phantom.catalogue.hanging`) and as a gap too short to measure already assumes: under
  the fitted ball's centre (:func:`_ball_axis`; the body's where no ball was fitted), which the post's
  stub and partial volume at the body's surface do not move as they move the body's;
- with fewer than ``MIN_OWN_SLABS`` slabs the radius is fitted to the post's whole silicone
  (:func:`_post_radius`) around the line it stands on, from the ball's surface to the base's, the
  ball's radius fitted again with it: the blur carries much of a post a slab or two tall into the
  inclusion's and the base's slabs. Where that shows a post and the scan has other pillars' slabs, the
  cross-section is the median over the slabs of all the scan's pillars that show one (the posts of one
  insert are cast alike); longer pillars keep their own. A gap too short to hold a slab takes the
  median radius of the scan's measured pillars, else that fit too (:func:`_gap_radius`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

MIN_RADIUS_MM = 0.5             # thinner posts are not told apart from noise
NOISE_Z = 3.0                   # median cross-section over its standard error
CORE_MARGIN_VOXELS = 1.5        # the core reaches this far beyond the pillar (blur, partial volume)
RING_GAP_VOXELS = 0.5
RING_WIDTH_MM = 2.5
HALF = 0.5                      # ring level / insert coverage at the base surface
MAX_TILT = math.tan(math.radians(30.0))
SHORT_GAP_SLABS = 2.5           # a closer base leaves too few slabs to measure a cross-section
GAP_AXIS_MM = 0.75              # the voxels this close to the line decide whether a short gap holds a post
MAD_TO_SIGMA = 1.4826
OUTLIER_SIGMAS = 3.0            # a ring's voxels further than this from its median are other structures
RING_LEVEL_ROUNDS = 5           # ... median and spread taken again over the rest, at most this often
MEDIAN_SE = 1.2533              # standard error of a median / (sigma / sqrt(n)) for normal scatter
SCALE_EPS = 1e-3
MIN_LINE_SLABS = 3              # fewer slabs do not place a line against noise: the inclusion's axis
MIN_OWN_SLABS = 4               # fewer slabs take the cross-section pooled over the scan's pillars
BASE_PLATEAU_SLABS = 3          # from this many slabs in the base, its level is their mean past the first
PROFILE_GEL_SLABS = 4           # the base surface's profile fit reads this many hydrogel slabs before it
PROFILE_AIR_SLABS = 2           # ... and this many slabs past the insert beyond the base
PROFILE_BLUR_SLABS = (0.2, 2.0)  # ... with its blur within this range, in slabs
PROFILE_MOVE_SLABS = 0.5        # ... moving the half-way crossing by less than this (at it: the crossing kept)
PROFILE_SPARE_SLABS = 2         # ... from this many slabs more than it has unknowns
BLUR_RANGE = (0.5, 2.0)         # a post's fitted blur, in units of the inclusion's it starts from
CLEAR_RING_MM = 4.0             # the annulus clear of a ball where the base's profile is read under a short post
SMOOTHING_TRUNCATE = 4.0        # the denoising's Gaussian, in its sigmas, as the F tests' correction reads it
OWN_LINE_P = 0.01               # a post leaves its inclusion's axis where its own line fits better at this level
CAP_SHUT_VOXELS = 1.0           # the ball's fit leaves out the core from this far inside the body's end on the base side
TESTED_SLABS = 3                # from this many slabs, a trace's cross-section is tested against their scatter
CLEAR_POST_RADIUS_MM = 0.7      # a significant post this wide (1.4 mm) outweighs a brief side of its inclusion


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
    return _Column(index, t_sel, np.stack([offsets @ e1, offsets @ e2], axis=1), fraction[index].astype(np.float64),
                   inside, inside & (ids == 0), deep[index], (ids != 0) & ~own, offsets + np.asarray(centre_mm), start)


def _slab(col: _Column, sign: int, st, step_mm: float) -> np.ndarray:
    """Slab index of depth ``st`` (mm beyond the inclusion on side ``sign``): slabs ``step_mm`` thick centred on
    the column's planes of voxel centres (slab 0 on ``col.start[sign]``, a voxel's). A slab's edge on a plane
    would split that slice's voxels between two slabs by the axis's slightest tilt (or by rounding), and read
    each slab's ring level between two slices."""
    return np.floor((np.asarray(st) - col.start[sign]) / step_mm + 0.5).astype(np.int64)


def _clear_of_ball(col: _Column, ball) -> np.ndarray:
    """The column's values with the inclusion's blurred ball (:class:`lesscli.mri.morphology.Ball`) taken
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
        spread = MAD_TO_SIGMA * float(np.median(np.abs(kept - level)))
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


def _trace(col: _Column, sign: int, line: np.ndarray, core_mm: float, ring_mm: tuple[float, float],
           step_mm: float, voxel_mm3: float, contrast: tuple[float, float], ball=None) -> Trace:
    """Slab profile beyond the inclusion on side ``sign``, around ``line`` = (offset (2,), slope (2,)).

    ``contrast`` = (local hydrogel level, local silicone - hydrogel) of the fraction image. ``ball``: the
    inclusion's fitted blurred ball (:class:`lesscli.mri.morphology.Ball`), whose silicone is taken out
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
    before_t, before = list(ts[max(j - PROFILE_GEL_SLABS, 0):j]), list(levels[max(j - PROFILE_GEL_SLABS, 0):j])
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


def _clear_end(fraction, insert, deep, inc_ids, label: int, centres: np.ndarray, balls: dict, axis: np.ndarray,
               spacing: np.ndarray, side: int, step_mm: float, voxel_mm3: float,
               contrast: tuple[float, float]) -> float | None:
    """The base surface under inclusion ``label`` (mm along ``side`` * ``axis`` from its body's centre, as
    :attr:`Trace.end_mm`) read in an annulus CLEAR_RING_MM wide around its fitted ball's axis, clear of the
    ball's blur (:func:`_clear_radius`) and of every other inclusion's, walked from up to PROFILE_GEL_SLABS + 2
    slabs beside the ball (not past its centre): the hydrogel before the base is read there, and the base's
    profile fitted (:func:`_base_crossing`). None without a fitted ball or where that fit is not decided either.

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
        near_other |= _from_line(col.uv, _ball_axis(other, centre, axis), col.t) <= _clear_radius(other, voxel)
    back = min(PROFILE_GEL_SLABS + 2, math.floor(col.start[side] / step_mm))
    col = replace(col, free=col.free & ~near_other, start={**col.start, side: col.start[side] - back * step_mm})
    trace = _trace(col, side, line, inner, (inner, inner + CLEAR_RING_MM), step_mm, voxel_mm3, contrast)
    return trace.end_mm if trace.profiled else None


def _own(col: _Column) -> np.ndarray:
    """The column's voxels of its own inclusion's body."""
    return col.inside & ~col.free & ~col.other


def _run_on(col: _Column, side: int, step_mm: float) -> bool:
    """The inclusion's body reaches more than a slab further towards the base than away from it: over a
    post a slab or so tall the opening that finds it keeps the post's slab and some of the base's."""
    return col.start[side] - col.start[-side] > step_mm


def _ball(fraction, allowed, inc_ids, label, col: _Column, side: int, core_mm: float, step_mm: float, spacing):
    """The inclusion's blurred ball, fitted away from other inclusions and from the column on the base side,
    from CAP_SHUT_VOXELS inside the body's end there: the post's silicone, blurred, reads within the ball's
    cap above it, and fitted with it, drew the ball's surface towards the post (by 0.1 mm over a 3 mm post
    1.2 mm tall at 0.95 mm voxels, whose radius, fitted below the ball, came out 0.08 mm short).

    Where the body runs on through a short post into the base (:func:`_run_on`), its own voxels past the
    other side's reach are not the ball's: taken as its, they put the base's silicone within the profile
    fitted, and the ball a fifth of a millimetre into the post."""
    from scipy import ndimage

    from lesscli.mri.morphology import RIM_VOXELS, fitted_ball

    sl = ndimage.find_objects(inc_ids, max_label=label)[label - 1]
    rho = _from_line(col.uv)
    st = side * col.t
    reach = col.start[-side] if _run_on(col, side, step_mm) else col.start[side]
    own = inc_ids == label
    shut = np.zeros(inc_ids.shape, dtype=bool)
    back = CAP_SHUT_VOXELS * float(spacing.max())
    shut[tuple(i[(rho <= core_mm) & (st > reach - back)] for i in col.index)] = True
    own[tuple(i[_own(col) & (st > reach)] for i in col.index)] = False
    ok = allowed & ~shut & ((inc_ids == 0) | own)
    fit = fitted_ball(own, fraction, ok, spacing, sl, RIM_VOXELS * float(spacing.max()))
    return fit if fit is not None and fit.radius_mm > 0 else None


def _fit_line(trace: Trace, fallback: np.ndarray) -> np.ndarray:
    """(offset, slope) of the lateral position against t, weighted by the excess; slope bounded."""
    ok = np.isfinite(trace.centroid_mm[:, 0]) & (trace.area_mm2 > 0)
    if ok.sum() == 0:
        return fallback
    w, t, c = trace.area_mm2[ok], trace.t_mm[ok], trace.centroid_mm[ok]
    if ok.sum() < 3:
        return np.stack([(w @ c) / w.sum(), np.zeros(2)])
    a = np.column_stack([np.ones_like(t), t]) * np.sqrt(w)[:, None]
    sol = np.linalg.lstsq(a, c * np.sqrt(w)[:, None], rcond=None)[0]
    slope = np.clip(sol[1], -MAX_TILT, MAX_TILT)
    return np.stack([sol[0], slope])


def _inner(trace: Trace) -> Trace:
    """Leave out the slab next to the inclusion and, from 3 slabs, the one next to the base (partial volume)."""
    n = len(trace.area_mm2)
    if n < 2:
        return trace
    keep = slice(1, n - 1 if n >= 3 else n)
    return replace(trace, t_mm=trace.t_mm[keep], area_mm2=trace.area_mm2[keep], centroid_mm=trace.centroid_mm[keep],
                   ring=trace.ring[keep])


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
    :meth:`~lesscli.mri.morphology.Ball.shell`; the post starts at the surface of the ball so fitted):
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
        """The post along its length, from the surface of the ball ``wider`` (mm) than fitted above each voxel."""
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


def _base_side(traces: dict, columns: dict, contrasts: dict, labels: list[int], core_mm: float, step_mm: float,
               voxel_mm3: float) -> int:
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
        gaps = {sign: _gap_area(columns[k], sign, traces[k, sign].end_mm, contrasts[k], core_mm, step_mm, voxel_mm3)
                for sign in short}
        gaps = {sign: max(area, math.pi * MIN_RADIUS_MM ** 2) for sign, area in gaps.items() if area is not None}
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


def disc_profile(rho_mm: np.ndarray, radius_mm: float, sigma_mm: float) -> np.ndarray:
    """A disc of ``radius_mm`` blurred by an isotropic Gaussian of ``sigma_mm``, at ``rho_mm`` from its centre (0-1):
    the chance that a 2D normal around that point lands in the disc (a noncentral chi-square with 2 degrees)."""
    from scipy.special import chndtr

    s2 = max(sigma_mm, 1e-6) ** 2
    return chndtr(radius_mm * radius_mm / s2, 2.0, rho_mm * rho_mm / s2)


def _cylinder_misfit(uv: np.ndarray, t: np.ndarray, excess: np.ndarray, line: np.ndarray, radius: float,
                     sigma: float) -> np.ndarray:
    """The blurred cylinder around ``line`` (:func:`fit_blurred_cylinder`) minus ``excess``, per voxel."""
    return disc_profile(_from_line(uv, line, t), radius, sigma) - excess


def fit_blurred_cylinder(uv: np.ndarray, t: np.ndarray, excess: np.ndarray, line: np.ndarray, radius: float,
                         sigma: float, core_mm: float, free_line: int = 4) -> tuple[np.ndarray, float, float]:
    """(line, radius, blur) of the straight cylinder under an isotropic Gaussian blur across it
    (:func:`disc_profile`) fitted by least squares to ``excess`` (silicone fraction over the local
    hydrogel, 0-1) at lateral positions ``uv`` (n, 2) and heights ``t`` (n,), mm; ``line`` = (offset (2,),
    slope (2,)) and ``radius`` start the fit, which keeps the line within ``core_mm`` of its start and
    tilted by at most MAX_TILT. ``free_line``: how many of the line's parameters are fitted (4: offset and
    slope; 2: the offset, the slope held; 0: the line held); the radius stays under ``core_mm``. The blur
    starts at ``sigma`` and stays within BLUR_RANGE times it."""
    from scipy.optimize import least_squares

    def unpack(p):
        return np.r_[p[:free_line], line.ravel()[free_line:]].reshape(2, 2), p[-2], p[-1]

    x0 = np.r_[line.ravel()[:free_line], radius, sigma]
    mid = np.r_[line[0], 0.0, 0.0][:free_line]            # the start's offset; no tilt
    reach = np.r_[core_mm, core_mm, MAX_TILT, MAX_TILT][:free_line]
    lo = np.r_[mid - reach, 0.25 * radius, BLUR_RANGE[0] * sigma]
    hi = np.r_[mid + reach, core_mm, BLUR_RANGE[1] * sigma]
    x = least_squares(lambda p: _cylinder_misfit(uv, t, excess, *unpack(p)), np.clip(x0, lo + 1e-9, hi - 1e-9),
                      bounds=(lo, hi)).x
    fitted, r, s = unpack(x)
    return fitted, float(r), float(s)


def _line_jacobian(uv: np.ndarray, t: np.ndarray, fit: tuple, free_line: int) -> np.ndarray:
    """(n, free_line + 2) derivatives of the blurred cylinder ``fit`` = (line, radius, blur) at each voxel by
    its fitted parameters (:func:`fit_blurred_cylinder`'s order), by central differences."""
    line, radius, blur = fit
    p0 = np.r_[line.ravel()[:free_line], radius, blur]

    def model(p):
        held = np.r_[p[:free_line], line.ravel()[free_line:]].reshape(2, 2)
        return disc_profile(_from_line(uv, held, t), p[-2], p[-1])

    steps = 1e-4 * np.maximum(1.0, np.abs(p0))
    return np.stack([(model(p0 + h * e) - model(p0 - h * e)) / (2 * h) for h, e in zip(steps, np.eye(len(p0)))], 1)


def _span(m: np.ndarray) -> np.ndarray:
    """Orthonormal columns spanning ``m``'s columns (those of a negligible singular value left out)."""
    u, s, _ = np.linalg.svd(m, full_matrices=False)
    return u[:, s > 1e-9 * max(float(s.max()), np.finfo(float).tiny)]


def _kept_by_smoothing(patterns: np.ndarray, index: tuple, smoothing: np.ndarray) -> np.ndarray:
    """The squared norm of each column of ``patterns`` (n, k), values at the voxels ``index`` (a tuple of
    (n,) grid indices), after the denoising's Gaussian of ``smoothing`` voxels per axis."""
    from scipy import ndimage

    lo = np.array([i.min() for i in index])
    pad = np.ceil(SMOOTHING_TRUNCATE * np.asarray(smoothing)).astype(int) + 1
    shape = tuple(np.array([i.max() for i in index]) - lo + 1 + 2 * pad)
    at = tuple(i - a + b for i, a, b in zip(index, lo, pad))
    out = []
    for q in patterns.T:
        grid = np.zeros(shape)
        grid[at] = q
        out.append(float(np.sum(ndimage.gaussian_filter(grid, smoothing, mode="constant",
                                                        truncate=SMOOTHING_TRUNCATE) ** 2)))
    return np.array(out)


def correlation_inflation(uv: np.ndarray, t: np.ndarray, fit: tuple, held: int, free_line: int, index: tuple,
                          smoothing: np.ndarray) -> float:
    """How much more the F statistic of ``fit`` (:func:`fit_blurred_cylinder`, ``free_line`` of its line's
    parameters fitted) over the same cylinder with only ``held`` of them fitted reads under noise that
    was white before the scan was denoised by a Gaussian of ``smoothing`` voxels per axis, than under
    white noise: the share of the noise the denoising keeps in the directions the extra parameters fit
    (their derivatives, clear of the other parameters', at the voxels ``index``) over its share in one
    voxel. Patterns as wide as the kernel keep it all (about 1 / (2 sqrt(pi) s)^3 over one voxel's share
    at s voxels: 10 at 0.6); a post's, 1-3 voxels across, 1.5-6 times as much as one voxel's."""
    jac = _line_jacobian(uv, t, fit, free_line)
    both, null = _span(jac), _span(np.delete(jac, np.s_[held:free_line], axis=1))
    extra = _span(both - null @ (null.T @ both))[:, :free_line - held]
    voxel = _kept_by_smoothing(np.ones((1, 1)), tuple(np.zeros(1, dtype=int) for _ in range(3)), smoothing)[0]
    return float(np.mean(_kept_by_smoothing(extra, index, smoothing))) / voxel


def own_or_centred(uv: np.ndarray, t: np.ndarray, excess: np.ndarray, line: np.ndarray, radius: float,
                   sigma: float, core_mm: float, centred: np.ndarray | None, index: tuple | None = None,
                   smoothing: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """(line, radius) of the post in ``excess`` (:func:`fit_blurred_cylinder`'s arguments): its own blurred
    cylinder, or, with ``centred`` (a line, offset and slope, through its inclusion's centre along the
    insert axis), the cylinder held on that line unless a line of the post's own fits significantly
    better (F tests at level OWN_LINE_P): first one along the insert axis (its offset fitted), then,
    past that, one also tilted (its slope fitted too).

    The phantoms are cast with each post under its sphere's centre, which the fitted ball of 6-16 mm
    places better than a post's few noisy voxels per slab place its own line: over the 700 volumes of
    the independent family (``tests/mri_family.py``, box partial volume) the posts' feet lay 0.041 mm
    off their true axes (median; 0.126 mm for one in ten) on their own lines, 0.031 mm (0.097 mm) so
    chosen when this choice came in. A post set off its inclusion's axis by more than the noise explains keeps its own line.
    Tested directly against the held line, the tilted line took 39 of 68 posts (family seeds 7000-7039,
    box), as much as 0.5 mm off at their ends in strong noise; tested in two steps, 26 are held, 31 take
    a straight line and 11 a tilted one.

    The scan's denoising (``smoothing``, its Gaussian's sigma per axis in voxels; ``index``, the voxels'
    grid indices) correlates the residuals of neighbouring voxels, and read as white each F statistic
    comes out 1.5-6 times too large (:func:`correlation_inflation`): the tests chose a post's own line
    for 42 of those 68 posts, all cast on their inclusions' axes. Each statistic is divided by that
    factor: 57 are held, 10 take a straight line and 1 a tilted one, and on seeds 7040-7139 (box) the
    feet lie 0.017 mm off the true axis (median; 90 % within 0.036 mm, 99 % within 0.078) against 0.019
    (0.060, 0.150). With the insert axis read from every voxel (:func:`lesscli.mri.morphology.insert_axis`;
    a random subsample had tilted it, and the line through the ball's centre along it, by up to 0.09 mm
    at the posts' middles), 65 of the 68 are held and 3 take straight lines.
    """
    from scipy.stats import f as f_dist

    own = fit_blurred_cylinder(uv, t, excess, line, radius, sigma, core_mm)
    if centred is None or len(excess) <= 6:
        return own[:2]
    start = np.stack([own[0][0] + (own[0][1] - centred[1]) * float(np.mean(t)), centred[1]])
    fits = [fit_blurred_cylinder(uv, t, excess, start if k else centred, own[1], own[2], core_mm, free_line=k)
            for k in (0, 2)] + [own]
    rss = [float(np.sum(_cylinder_misfit(uv, t, excess, *fit) ** 2)) for fit in fits]
    chosen = 0
    for k in (1, 2):
        dof = len(excess) - 2 - 2 * k
        f = (rss[chosen] - rss[k]) / (2 * (k - chosen)) / max(rss[k] / dof, np.finfo(float).tiny)
        level = f_dist.isf(OWN_LINE_P, 2 * (k - chosen), dof)
        if f > level and index is not None and smoothing is not None and np.any(np.asarray(smoothing) > 0):
            f /= correlation_inflation(uv, t, fits[k], 2 * chosen, 2 * k, index, smoothing)   # only lowers f
        if f > level:
            chosen = k
    return fits[chosen][:2]


def _fit_cylinder(col: _Column, sign: int, trace: Trace, line: np.ndarray, radius: float, core_mm: float,
                  step_mm: float, contrast: tuple[float, float], ball, centred: np.ndarray | None,
                  smoothing: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """(line, radius) of :func:`own_or_centred` on the core's silicone in ``trace``'s slabs, each over its
    ring level and in units of the inclusion's contrast over it, from ``line`` and ``radius`` and the
    inclusion's blur (``ball``, the scan's own; half a slab without one), whose silicone is taken out
    first; ``centred``: the line along the insert axis through the ball's centre (None without a ball)."""
    value = _clear_of_ball(col, ball)
    st = sign * col.t
    lo_t, hi_t = trace.t_mm[0] - 0.5 * step_mm, trace.t_mm[-1] + 0.5 * step_mm
    rho0 = _from_line(col.uv, line, st)
    sel = col.free & (st >= lo_t) & (st < hi_t) & (rho0 <= core_mm)
    if sel.sum() < 8:
        return line, radius
    bg = np.interp(st[sel], trace.t_mm, trace.ring)
    scale = np.maximum(contrast[0] + contrast[1] - bg, SCALE_EPS)
    excess = (value[sel] - bg) / scale
    return own_or_centred(col.uv[sel], st[sel], excess, line, radius, _blur_mm(ball, step_mm), core_mm, centred,
                          tuple(i[sel] for i in col.index), smoothing)


def _contrast(fraction: np.ndarray, inc_ids: np.ndarray, label: int, col: _Column, ring_mm,
              spacing) -> tuple[float, float]:
    """(hydrogel level, silicone - hydrogel): the inclusion's interior against the column's ring."""
    from scipy import ndimage

    sl = ndimage.find_objects(inc_ids, max_label=label)[label - 1]
    own = np.pad(inc_ids[sl] == label, 1)
    depth = ndimage.distance_transform_edt(own, sampling=spacing)[1:-1, 1:-1, 1:-1]
    interior = (depth > float(spacing.max())) if (depth > float(spacing.max())).any() else own[1:-1, 1:-1, 1:-1]
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


def find_pillars(fraction: np.ndarray, insert: np.ndarray, inc_ids: np.ndarray, n_inclusions: int,
                 spacing_mm, axis: np.ndarray, max_diameter_mm: float,
                 deep: np.ndarray | None = None,
                 diameter_mm: float | None = None,
                 smoothing: np.ndarray | None = None) -> tuple[np.ndarray, list[int], int]:
    """The pillar under each inclusion, traced towards the base.

    Args:
        fraction: 3D float silicone fraction (0 hydrogel, 1 silicone; bias-corrected, any smoothing).
        insert: bool mask of the insert (holes filled); inc_ids: int labels 1..n of the inclusions.
        n_inclusions: number of inclusion labels.
        spacing_mm: (3,) voxel size per axis.
        axis: (3,) unit insert axis (array-axis components of mm vectors), either sign.
        max_diameter_mm: thickest pillar (sizes the search around each inclusion's line).
        deep: bool mask of the insert away from its outer surface (where the base's level is read);
            None: the insert.
        diameter_mm: the posts' diameter as cast, where known: every post is found, placed and ended
            as without it, then drawn this wide; None: as measured.
        smoothing: (3,) sigma per axis, in voxels, of the Gaussian the scan was denoised with (the F tests of
            :func:`own_or_centred` read its correlated noise); None: white noise.

    Returns:
        (pillar mask, labels of the inclusions without a pillar, the base's surface (:class:`BaseSurface`),
        None where no pillar was found), the posts drawn (:class:`Post`, in the order of the inclusions'
        labels), the inclusions' voxels past their fitted balls where a body runs on through a short post
        into the base (:func:`_run_on`: not the inclusion's)).
    """
    spacing = np.asarray(spacing_mm, dtype=np.float64)
    pillar = np.zeros(insert.shape, dtype=bool)
    if n_inclusions == 0:
        return pillar, [], None, [], pillar.copy()
    from scipy import ndimage

    voxel = float(spacing.max())
    along = int(np.argmax(np.abs(axis)))          # slabs one plane of voxel centres thick (the module's docstring)
    step, voxel_mm3 = float(spacing[along] / abs(axis[along])), float(np.prod(spacing))

    def rings(core):
        inner = core + RING_GAP_VOXELS * voxel
        return inner, inner + max(RING_WIDTH_MM, 2 * voxel)

    core0 = 0.5 * max_diameter_mm + CORE_MARGIN_VOXELS * voxel
    labels = list(range(1, n_inclusions + 1))
    centres = np.asarray(ndimage.center_of_mass(inc_ids > 0, inc_ids, labels)).reshape(-1, 3) * spacing
    columns, contrasts, traces = {}, {}, {}
    for label, centre in zip(labels, centres):
        col = _column(fraction, insert, insert if deep is None else deep, inc_ids, label, centre, axis, spacing,
                      rings(core0)[1])
        contrast = _contrast(fraction, inc_ids, label, col, rings(core0), spacing)
        for _ in range(2):          # the hydrogel level again, from the slabs walked on either side
            both = [_trace(col, sign, np.zeros((2, 2)), core0, rings(core0), step, voxel_mm3, contrast)
                    for sign in (1, -1)]
            contrast = _walked_contrast(both, contrast)
        columns[label], contrasts[label] = col, contrast
        traces[label, 1], traces[label, -1] = both
    side = _base_side(traces, columns, contrasts, labels, core0, step, voxel_mm3)
    balls, under = {}, {}                   # under: the line through each fitted ball's centre (the body's)
    run_on = np.zeros(insert.shape, dtype=bool)
    for label, centre in zip(labels, centres):
        ball = balls[label] = _ball(fraction, insert if deep is None else deep, inc_ids, label, columns[label],
                                    side, core0, step, spacing)
        under[label] = _ball_axis(ball, centre, axis)
        col = columns[label]
        if ball is not None and _run_on(col, side, step):
            run_on[tuple(i[_beyond_ball(col, side, ball, centre, axis)] for i in col.index)] = True
        if ball is not None and _short_gap(traces[label, side], col, side, step):
            col = _past_ball(col, side, ball, centre, axis)
        if col is not columns[label]:
            columns[label] = col
            traces[label, side] = _trace(col, side, np.zeros((2, 2)), core0, rings(core0), step, voxel_mm3,
                                         contrasts[label])
    found, finals, short, missing = {}, {}, [], []
    clear = {}                              # label -> the base surface read clear of its ball, once needed

    def base_end(label, trace):
        """``trace``'s base surface, or where too few of its slabs decided the base's profile, the one read
        clear of the inclusion's ball (:func:`_clear_end`) where that is decided."""
        if trace.profiled is not False:
            return trace.end_mm
        if label not in clear:
            clear[label] = _clear_end(fraction, insert, insert if deep is None else deep, inc_ids, label, centres,
                                      balls, axis, spacing, side, step, voxel_mm3, contrasts[label])
        return trace.end_mm if clear[label] is None else clear[label]

    scatter = _pooled_scatter(_inner(trace) for trace in traces.values())
    thin_core = 0.25 * max_diameter_mm + CORE_MARGIN_VOXELS * voxel       # half the widest pillar's, less noise
    thin = {}                               # every trace again in the thin core, read once if one is needed
    for label in labels:
        first = _inner(traces[label, side])
        if not first.significant(scatter):
            if not thin:
                thin = {key: _inner(_trace(columns[key[0]], key[1], np.zeros((2, 2)), thin_core, rings(thin_core),
                                           step, voxel_mm3, contrasts[key[0]])) for key in traces}
                thin_scatter = _pooled_scatter(thin.values())
            first = thin[label, side] if thin[label, side].significant(thin_scatter) else None
        if first is None:
            (short if _short_gap(traces[label, side], columns[label], side, step) else missing).append(label)
            continue
        col, line = columns[label], _fit_line(first, np.zeros((2, 2)))
        core = min(core0, _disc_radius(first.median_area()) + CORE_MARGIN_VOXELS * voxel)
        second = _trace(col, side, line, core, rings(core), step, voxel_mm3, contrasts[label], balls[label])
        final = _inner(second) if len(second.area_mm2) else first
        line = _fit_line(final, line) if len(final.area_mm2) >= MIN_LINE_SLABS else under[label]
        found[label], finals[label] = (line, final.area_mm2, core, base_end(label, second)), final
    cores = {label: core for label, (_line, _areas, core, _end) in found.items()}

    def short_radius(label, core, end):
        ball = balls[label]                 # from the inclusion's fitted surface under its centre
        start = columns[label].start[side] if ball is None else _ball_surface(ball, centres[label - 1], axis, side)
        return _post_radius(columns[label], side, start, end, ball, contrasts[label], core, rings(core), step,
                            voxel_mm3, under[label])

    found = _pooled_radii(found, short_radius)
    for label, final in finals.items():     # line, radius and blur refined together: one blurred cylinder
        if len(final.area_mm2) >= MIN_LINE_SLABS:
            line, radius, end = found[label]
            line, fitted = _fit_cylinder(columns[label], side, final, line, radius, cores[label], step,
                                         contrasts[label], balls[label], None if balls[label] is None else under[label],
                                         smoothing)
            if len(final.area_mm2) >= MIN_OWN_SLABS:        # its own slabs must show a post too
                radius = fitted if radius >= MIN_RADIUS_MM else 0.0
            found[label] = (line, radius, end)
    for label in [k for k, (_line, radius, _end) in found.items() if radius < MIN_RADIUS_MM]:
        del found[label]                # measured thinner than noise tells apart: no post after all
        missing.append(label)
    for label in short:                 # too close to the base to measure: silicone across the gap, or none
        col, end = columns[label], base_end(label, traces[label, side])
        radius = _gap_radius(col, side, end, contrasts[label], core0, step, voxel_mm3, found, under[label],
                             max_diameter_mm, None if balls[label] is None else partial(short_radius, label, core0, end))
        if radius is None:
            missing.append(label)
        else:
            found[label] = (under[label], radius, end)
    measured = {}                           # label -> the radius measured, where the one drawn is given
    if diameter_mm is not None:
        measured = {label: radius for label, (_line, radius, _end) in found.items()}
        found = {label: (line, 0.5 * diameter_mm, end) for label, (line, _radius, end) in found.items()}
    for label, (line, radius, end) in found.items():
        col = columns[label]
        st = side * col.t
        rho = _from_line(col.uv, line, st)
        sel = col.inside & ~col.other & (rho <= radius) & (st >= 0) & (st <= end)
        pillar[tuple(i[sel] for i in col.index)] = True
    base = None
    if found:                               # one cast plane: the median of where the posts met it
        base = BaseSurface(side * axis, float(np.median([side * float(centres[label - 1] @ axis) + end
                                                         for label, (_line, _radius, end) in found.items()])))
    posts = [_post(*found[label], centres[label - 1], axis, side,
                   columns[label].start[side] if balls[label] is None
                   else _ball_surface(balls[label], centres[label - 1], axis, side),
                   measured.get(label)) for label in sorted(found)]
    return pillar, sorted(missing), base, posts, run_on


def _post(line: np.ndarray, radius: float, end: float, centre: np.ndarray, axis: np.ndarray, side: int,
          start: float, measured: float | None = None) -> Post:
    """The :class:`Post` drawn around ``line`` (lateral offset and slope against the distance ``st`` from
    ``centre`` towards the base, :func:`_trace`'s frame) from ``start`` (the inclusion's surface) to ``end``
    (the base's); ``measured``: its radius measured where ``radius`` was given."""
    e1, e2 = _basis(axis)

    def at(st):
        u, v = line[0] + st * line[1]
        return centre + side * st * axis + u * e1 + v * e2

    up = at(0.0) - at(1.0)
    return Post(at(end), up / np.linalg.norm(up), radius, end - start, measured)


@dataclass
class Post:
    """One pillar as drawn: a straight cylinder standing on the base's surface. Points in millimetres along
    the array axes from the first voxel's centre (index times spacing)."""

    foot_mm: np.ndarray             # the centre of its end on the base (where its own trace met the base)
    direction: np.ndarray           # unit, from the foot towards its inclusion
    radius_mm: float
    height_mm: float                # from the base's surface to the inclusion's, along the insert axis
    measured_radius_mm: float | None = None     # as the scan measured it, where the radius drawn was given

    def shifted(self, origin_index: np.ndarray, spacing: np.ndarray) -> Post:
        """The same post on a grid (of the same spacing) whose index 0 lies at this one's ``origin_index``."""
        return replace(self, foot_mm=self.foot_mm - np.asarray(origin_index) * spacing)


@dataclass
class BaseSurface:
    """The base's surface under the filling, found under the posts: the plane ``normal . x = offset_mm``,
    x in millimetres along the array axes from the first voxel's centre (index times spacing), the unit
    ``normal`` pointing into the base."""

    normal: np.ndarray
    offset_mm: float

    def past_mm(self, spacing: np.ndarray, shape: tuple) -> np.ndarray:
        """How far each voxel's centre lies past the surface, mm: positive in the base's silicone (which no
        inclusion's ball holds), negative on the filling's side."""
        d = np.meshgrid(*(np.arange(n) * s * a for n, s, a in zip(shape, spacing, self.normal)), indexing="ij",
                        sparse=True)
        return d[0] + d[1] + d[2] - self.offset_mm

    def shifted(self, origin_index: np.ndarray, spacing: np.ndarray) -> BaseSurface:
        """The same plane on a grid (of the same spacing) whose index 0 lies at this one's ``origin_index``."""
        return BaseSurface(self.normal, self.offset_mm - float(self.normal @ (np.asarray(origin_index) * spacing)))
