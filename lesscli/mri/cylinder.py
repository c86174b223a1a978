"""A straight blurred cylinder: its profile across the axis (:func:`disc_profile`), its least-squares fit to a
post's voxels (:func:`fit_blurred_cylinder`), and the F tests that decide whether a post leaves its
inclusion's
axis (:func:`own_or_centred`), read with the correlation the scan's denoising put into its noise."""

from __future__ import annotations

import math

import numpy as np

from lesscli.mri.column import SCALE_EPS, _blur_mm, _clear_of_ball, _Column, _from_line
from lesscli.mri.trace import Trace

MAX_TILT = math.tan(math.radians(30.0))
BLUR_RANGE = (0.5, 2.0)         # a post's fitted blur, in units of the inclusion's it starts from
SMOOTHING_TRUNCATE = 4.0        # the denoising's Gaussian, in its sigmas, as the F tests' correction reads it
# a post leaves its inclusion's axis where its own line fits better at this level
OWN_LINE_P = 0.01


def disc_profile(rho_mm: np.ndarray, radius_mm: float, sigma_mm: float) -> np.ndarray:
    """A disc of ``radius_mm`` blurred by an isotropic Gaussian of ``sigma_mm``, at ``rho_mm`` from its centre
    (0-1):
    the chance that a 2D normal around that point lands in the disc (a noncentral chi-square with 2
    degrees)."""
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
    x = least_squares(lambda p: _cylinder_misfit(uv, t, excess, *unpack(p)),
                      np.clip(x0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi)).x
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
    return np.stack([(model(p0 + h * e) - model(p0 - h * e)) / (2 * h) for h,
                     e in zip(steps, np.eye(len(p0)))], 1)


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
    chosen when this choice came in. A post set off its inclusion's axis by more than the noise explains keeps
    its own line. Tested directly against the held line, the tilted line took 39 of 68 posts (family seeds
    7000-7039, box), as much as 0.5 mm off at their ends in strong noise; tested in two steps, 26 are held, 31
    take a straight line and 11 a tilted one.

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
    from scipy.special import fdtri  # the F distribution's quantile (scipy.stats' f.isf, without its import)

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
        level = float(fdtri(2 * (k - chosen), dof, 1.0 - OWN_LINE_P))
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
    return own_or_centred(col.uv[sel], st[sel], excess, line, radius, _blur_mm(ball, step_mm), core_mm,
                          centred, tuple(i[sel] for i in col.index), smoothing)
