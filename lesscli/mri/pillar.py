"""Pillars: the thin silicone post between each inclusion and the base, traced along the insert axis.

Nothing here assumes a pillar's diameter, intensity or which end of the insert the base is at. Around
the line through each inclusion's centre the insert is cut into slabs one voxel thick; in each, the
core's silicone in excess of a surrounding ring, divided by the inclusion's contrast, is the post's
cross-section. A sum is unchanged by partial volume and blur, so no threshold is involved and a post 1-2
voxels wide is measured like a wide one. The post drawn is a blurred cylinder fitted to the slabs; the
rules are in :func:`find_pillars`, and how each was found in docs/results/mri-label-rounds.md.

The steps use :mod:`lesscli.mri.column` (a column, its slabs and rings), :mod:`lesscli.mri.trace` (a
trace and the base's surface it meets), :mod:`lesscli.mri.section` (a post's cross-section, the base's
side), :mod:`lesscli.mri.cylinder` (the blurred cylinder's fit and its F tests) and
:mod:`lesscli.mri.ball` (the inclusion's blurred ball).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from lesscli.mri.ball import _column_ball
from lesscli.mri.column import (
    _ball_axis,
    _ball_surface,
    _basis,
    _beyond_ball,
    _column,
    _from_line,
    _past_ball,
    _run_on,
)
from lesscli.mri.cylinder import MAX_TILT, _fit_cylinder
from lesscli.mri.section import (
    MIN_OWN_SLABS,
    _base_side,
    _disc_radius,
    _gap_radius,
    _inner,
    _pooled_radii,
    _post_radius,
    _short_gap,
)
from lesscli.mri.trace import (
    MIN_RADIUS_MM,
    Trace,
    _clear_end,
    _contrast,
    _pooled_scatter,
    _trace,
    _walked_contrast,
)

CORE_MARGIN_VOXELS = 1.5        # the core reaches this far beyond the pillar (blur, partial volume)
RING_GAP_VOXELS = 0.5
RING_WIDTH_MM = 2.5
MIN_LINE_SLABS = 3              # fewer slabs do not place a line against noise: the inclusion's axis


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


def find_pillars(fraction: np.ndarray, insert: np.ndarray, inc_ids: np.ndarray, n_inclusions: int,
                 spacing_mm, axis: np.ndarray, max_diameter_mm: float,
                 deep: np.ndarray | None = None,
                 diameter_mm: float | None = None,
                 smoothing: np.ndarray | None = None
                 ) -> tuple[np.ndarray, list[int], BaseSurface | None, list[Post], np.ndarray]:
    """The pillar under each inclusion, traced towards the base.

    Per slab on both sides of each inclusion (its fitted blurred ball taken out of every voxel first, as
    its blur spreads silicone along the pillar's line): a ring around the core gives the local background
    (a median clipped of far voxels, so a nearby wall's skin does not raise it); the trace ends where the
    ring turns silicone or leaves the insert, at the base's surface fitted to the ring levels around the
    crossing; the weighted centroid of the excess locates the post in the slab.

    The base is on the side where the inclusions together show more excess silicone. An inclusion has a
    pillar there when the median cross-section exceeds a disc of ``MIN_RADIUS_MM`` and ``NOISE_Z``
    standard errors of the slab-to-slab scatter pooled over the scan's traces, in a wide core or a narrow
    one. The cylinder is held on its inclusion's axis (as the phantoms are cast) unless its own line fits
    significantly better; a post measured thinner than ``MIN_RADIUS_MM`` is no post. Under
    ``MIN_LINE_SLABS`` slabs the post stands under the inclusion's centre, and under ``MIN_OWN_SLABS`` its
    radius is fitted to its whole silicone with the ball, or pooled over the scan's other posts.

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
    if n_inclusions == 0:
        none = np.zeros(insert.shape, dtype=bool)
        return none, [], None, [], none.copy()
    search = _Search(fraction, insert, insert if deep is None else deep, inc_ids, n_inclusions, spacing_mm,
                     axis, max_diameter_mm, smoothing)
    search.walk()
    search.side = _base_side(search.traces, search.columns, search.contrasts, search.labels, search.core0,
                             search.step, search.voxel_mm3)
    run_on = search.fit_balls()
    found, finals, short, missing = search.measure()
    cores = {label: core for label, (_line, _areas, core, _end) in found.items()}
    found = _pooled_radii(found, search.short_radius)
    search.refine(found, finals, cores, missing)
    search.bridge(found, short, missing)
    pillar, base, posts = search.draw(found, diameter_mm)
    return pillar, sorted(missing), base, posts, run_on


class _Search:
    """One scan's search for its pillars (:func:`find_pillars`), step by step; each step keeps what it finds
    for the next: the columns, their contrasts and traces, the fitted balls and the lines under them."""

    def __init__(self, fraction: np.ndarray, insert: np.ndarray, deep: np.ndarray, inc_ids: np.ndarray,
                 n_inclusions: int, spacing_mm, axis: np.ndarray, max_diameter_mm: float,
                 smoothing: np.ndarray | None):
        from scipy import ndimage

        self.fraction, self.insert, self.deep, self.inc_ids = fraction, insert, deep, inc_ids
        self.spacing = np.asarray(spacing_mm, dtype=np.float64)
        self.axis, self.max_diameter_mm, self.smoothing = axis, max_diameter_mm, smoothing
        self.voxel = float(self.spacing.max())
        # slabs one plane of voxel centres thick (the module's docstring)
        along = int(np.argmax(np.abs(axis)))
        self.step, self.voxel_mm3 = (float(self.spacing[along] / abs(axis[along])),
                                     float(np.prod(self.spacing)))
        self.core0 = 0.5 * max_diameter_mm + CORE_MARGIN_VOXELS * self.voxel
        self.labels = list(range(1, n_inclusions + 1))
        centres = ndimage.center_of_mass(inc_ids > 0, inc_ids, self.labels)
        self.centres = np.asarray(centres).reshape(-1, 3) * self.spacing
        self.columns, self.contrasts, self.traces = {}, {}, {}
        self.balls, self.under = {}, {}     # under: the line through each fitted ball's centre (the body's)
        self.clear = {}                     # label -> the base surface read clear of its ball, once needed
        self.side = 0

    def rings(self, core: float) -> tuple[float, float]:
        inner = core + RING_GAP_VOXELS * self.voxel
        return inner, inner + max(RING_WIDTH_MM, 2 * self.voxel)

    def trace(self, label: int, sign: int, core: float, line: np.ndarray | None = None, ball=None) -> Trace:
        return _trace(self.columns[label], sign, np.zeros((2, 2)) if line is None else line, core,
                      self.rings(core), self.step, self.voxel_mm3, self.contrasts[label], ball)

    def walk(self) -> None:
        """Each inclusion's column and its first traces on both sides, the hydrogel level taken again from the
        slabs walked on either side."""
        for label, centre in zip(self.labels, self.centres):
            self.columns[label] = _column(self.fraction, self.insert, self.deep, self.inc_ids, label, centre,
                                          self.axis, self.spacing, self.rings(self.core0)[1])
            self.contrasts[label] = _contrast(self.fraction, self.inc_ids, label, self.columns[label],
                                              self.rings(self.core0), self.spacing)
            for _ in range(2):
                both = [self.trace(label, sign, self.core0) for sign in (1, -1)]
                self.contrasts[label] = _walked_contrast(both, self.contrasts[label])
            self.traces[label, 1], self.traces[label, -1] = both

    def fit_balls(self) -> np.ndarray:
        """Each inclusion's blurred ball and the line under its centre; a column whose gap to the base is
        short
        walked again past its ball. Returns the voxels past the balls where a body runs on into the base."""
        side = self.side
        run_on = np.zeros(self.insert.shape, dtype=bool)
        for label, centre in zip(self.labels, self.centres):
            ball = self.balls[label] = _column_ball(self.fraction, self.deep, self.inc_ids, label,
                                                    self.columns[label], side, self.core0, self.step,
                                                    self.spacing)
            self.under[label] = _ball_axis(ball, centre, self.axis)
            col = self.columns[label]
            if ball is not None and _run_on(col, side, self.step):
                run_on[tuple(i[_beyond_ball(col, side, ball, centre, self.axis)] for i in col.index)] = True
            if ball is not None and _short_gap(self.traces[label, side], col, side, self.step):
                col = _past_ball(col, side, ball, centre, self.axis)
            if col is not self.columns[label]:
                self.columns[label] = col
                self.traces[label, side] = self.trace(label, side, self.core0)
        return run_on

    def base_end(self, label: int, trace: Trace) -> float:
        """``trace``'s base surface, or where too few of its slabs decided the base's profile, the one read
        clear of the inclusion's ball (:func:`_clear_end`) where that is decided."""
        if trace.profiled is not False:
            return trace.end_mm
        if label not in self.clear:
            self.clear[label] = _clear_end(self.fraction, self.insert, self.deep, self.inc_ids, label,
                                           self.centres, self.balls, self.axis, self.spacing, self.side,
                                           self.step, self.voxel_mm3, self.contrasts[label])
        return trace.end_mm if self.clear[label] is None else self.clear[label]

    def measure(self) -> tuple[dict, dict, list[int], list[int]]:
        """The posts the traces on the base's side show: label -> (line, slab cross-sections, core radius,
        end),
        label -> the trace measured, the labels across a short gap, and those without a post."""
        side, voxel = self.side, self.voxel
        scatter = _pooled_scatter(_inner(trace) for trace in self.traces.values())
        # half the widest pillar's, less noise
        thin_core = 0.25 * self.max_diameter_mm + CORE_MARGIN_VOXELS * voxel
        thin = {}                           # every trace again in the thin core, read once if one is needed
        found, finals, short, missing = {}, {}, [], []
        for label in self.labels:
            first = _inner(self.traces[label, side])
            if not first.significant(scatter):
                if not thin:
                    thin = {key: _inner(self.trace(key[0], key[1], thin_core)) for key in self.traces}
                    thin_scatter = _pooled_scatter(thin.values())
                first = thin[label, side] if thin[label, side].significant(thin_scatter) else None
            if first is None:
                gap = _short_gap(self.traces[label, side], self.columns[label], side, self.step)
                (short if gap else missing).append(label)
                continue
            line = _fit_line(first, np.zeros((2, 2)))
            core = min(self.core0, _disc_radius(first.median_area()) + CORE_MARGIN_VOXELS * voxel)
            second = self.trace(label, side, core, line, self.balls[label])
            final = _inner(second) if len(second.area_mm2) else first
            line = _fit_line(final, line) if len(final.area_mm2) >= MIN_LINE_SLABS else self.under[label]
            found[label], finals[label] = (line, final.area_mm2, core, self.base_end(label, second)), final
        return found, finals, short, missing

    def short_radius(self, label: int, core: float, end: float) -> float:
        """A short post's radius fitted to its whole silicone (:func:`_post_radius`), from its inclusion's
        fitted surface under its centre to ``end``."""
        ball, side = self.balls[label], self.side
        start = (self.columns[label].start[side] if ball is None
                 else _ball_surface(ball, self.centres[label - 1], self.axis, side))
        return _post_radius(self.columns[label], side, start, end, ball, self.contrasts[label], core,
                            self.rings(core), self.step, self.voxel_mm3, self.under[label])

    def refine(self, found: dict, finals: dict, cores: dict, missing: list[int]) -> None:
        """Line, radius and blur of each post with slabs enough refined together (one blurred cylinder); a
        post measured thinner than noise tells apart moves from ``found`` to ``missing``."""
        for label, final in finals.items():
            if len(final.area_mm2) >= MIN_LINE_SLABS:
                line, radius, end = found[label]
                ball = self.balls[label]
                line, fitted = _fit_cylinder(self.columns[label], self.side, final, line, radius,
                                             cores[label], self.step, self.contrasts[label], ball,
                                             None if ball is None else self.under[label], self.smoothing)
                if len(final.area_mm2) >= MIN_OWN_SLABS:        # its own slabs must show a post too
                    radius = fitted if radius >= MIN_RADIUS_MM else 0.0
                found[label] = (line, radius, end)
        for label in [k for k, (_line, radius, _end) in found.items() if radius < MIN_RADIUS_MM]:
            del found[label]
            missing.append(label)

    def bridge(self, found: dict, short: list[int], missing: list[int]) -> None:
        """The inclusions too close to the base to measure a post on slabs: silicone across the gap (into
        ``found``, under the ball's centre), or none (into ``missing``)."""
        for label in short:
            col, end = self.columns[label], self.base_end(label, self.traces[label, self.side])
            fitted = None if self.balls[label] is None else partial(self.short_radius, label, self.core0, end)
            radius = _gap_radius(col, self.side, end, self.contrasts[label], self.core0, self.step,
                                 self.voxel_mm3, found, self.under[label], self.max_diameter_mm, fitted)
            if radius is None:
                missing.append(label)
            else:
                found[label] = (self.under[label], radius, end)

    def draw(self, found: dict,
             diameter_mm: float | None) -> tuple[np.ndarray, BaseSurface | None, list[Post]]:
        """The pillar mask, the base's surface (one cast plane: the median of where the posts met it) and the
        posts of ``found`` (label -> (line, radius, end)), each ``diameter_mm`` wide where that is given."""
        side, axis = self.side, self.axis
        measured = {}                       # label -> the radius measured, where the one drawn is given
        if diameter_mm is not None:
            measured = {label: radius for label, (_line, radius, _end) in found.items()}
            found = {label: (line, 0.5 * diameter_mm, end) for label, (line, _radius, end) in found.items()}
        pillar = np.zeros(self.insert.shape, dtype=bool)
        for label, (line, radius, end) in found.items():
            col = self.columns[label]
            st = side * col.t
            rho = _from_line(col.uv, line, st)
            sel = col.inside & ~col.other & (rho <= radius) & (st >= 0) & (st <= end)
            pillar[tuple(i[sel] for i in col.index)] = True
        base = None
        if found:
            base = BaseSurface(side * axis,
                               float(np.median([side * float(self.centres[label - 1] @ axis) + end
                                                             for label,
                                                             (_line, _radius, end) in found.items()])))
        posts = [_post(*found[label], self.centres[label - 1], axis, side,
                       self.columns[label].start[side] if self.balls[label] is None
                       else _ball_surface(self.balls[label], self.centres[label - 1], axis, side),
                       measured.get(label)) for label in sorted(found)]
        return pillar, base, posts


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
        d = np.meshgrid(*(np.arange(n) * s * a for n, s, a in zip(shape, spacing, self.normal)),
                        indexing="ij", sparse=True)
        return d[0] + d[1] + d[2] - self.offset_mm

    def shifted(self, origin_index: np.ndarray, spacing: np.ndarray) -> BaseSurface:
        """The same plane on a grid (of the same spacing) whose index 0 lies at this one's
        ``origin_index``."""
        return BaseSurface(self.normal,
                           self.offset_mm - float(self.normal @ (np.asarray(origin_index) * spacing)))
