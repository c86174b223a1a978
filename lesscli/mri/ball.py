"""A blurred ball fitted to a body's silicone (:class:`Ball`, :func:`fitted_ball`): its centre, radius, blur
and contrast over the filling, fitted to the body's own profile; where its surface lies in the scan (below
half-way on a curved surface: the blur spreads a small body's silicone outwards), and how well a ball is all
the voxels show. Inclusions are re-thresholded with it (:mod:`lesscli.mri.morphology`) and pillars traced
with it taken out (:mod:`lesscli.mri.pillar`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lesscli.mri.column import _Column, _from_line, _own, _run_on
from lesscli.robust import robust_sigma

# an inclusion's image surface moves at most this far from the opening, in (largest) voxels
RIM_VOXELS = 1.0
LEVEL_VOXELS = (2.0, 4.0)       # the filling's level is measured this far outside an inclusion, in voxels
# the blurred-ball profile is fitted to the voxels this close to a body, in voxels
PROFILE_VOXELS = 2.0
PROFILE_SHIFT_VOXELS = 1.0      # ... its centre within this of the body's centroid
PROFILE_RADIUS = (0.5, 1.5)     # ... its radius within these factors of the body's equal-volume radius
PROFILE_SIGMA_VOXELS = (0.1, 3.0)   # ... its blur within these, in voxels
PROFILE_CONTRAST = (0.5, 2.0)   # ... its contrast within these factors of the interior's over the filling
# the ball's fit leaves out the core from this far inside the body's end on the base side
CAP_SHUT_VOXELS = 1.0


@dataclass
class Ball:
    """A blurred ball fitted to a body: ``centre_mm`` (array-axis mm), ``radius_mm``, ``sigma_mm`` (blur),
    ``contrast`` over ``filling`` (fraction units); ``level`` the surface level; ``box`` and ``near`` the
    region (within the rim of the body) where the surface is re-thresholded, on a grid of ``spacing_mm``;
    ``misfit`` the root-mean-square residual of the fit over the scan's noise (the robust spread of the
    filling around it): about 1 where a ball is all the voxels show, inf where no fit was made."""

    centre_mm: np.ndarray
    radius_mm: float
    sigma_mm: float
    contrast: float
    filling: float
    level: float
    box: tuple
    near: np.ndarray
    spacing_mm: np.ndarray
    misfit: float = math.inf

    def inside(self) -> np.ndarray:
        """(``near``'s shape) bool: the voxels of ``box`` whose centres lie in the ball."""
        origin = np.array([b.start for b in self.box], dtype=np.float64) * self.spacing_mm
        axes = [(np.arange(n) * s + o - c) ** 2
                for n, s, o, c in zip(self.near.shape, self.spacing_mm, origin, self.centre_mm)]
        return axes[0][:, None, None] + axes[1][None, :, None] + axes[2][None, None, :] <= self.radius_mm ** 2

    def excess(self, points_mm: np.ndarray) -> np.ndarray:
        """The ball's blurred silicone over the filling at ``points_mm`` (n, 3)."""
        r = np.linalg.norm(points_mm - self.centre_mm, axis=1)
        return self.contrast * ball_profile(r, self.radius_mm, self.sigma_mm)

    def shell(self, points_mm: np.ndarray) -> np.ndarray:
        """How much :meth:`excess` grows at ``points_mm`` (n, 3) per millimetre of radius: the blur's normal
        summed over the ball's surface, ``R / (r sigma sqrt(2 pi)) (exp(-(R - r)^2 / 2 sigma^2) - exp(-(R +
        r)^2 / 2 sigma^2))`` times the contrast."""
        r = np.maximum(np.linalg.norm(points_mm - self.centre_mm, axis=1), 1e-6 * self.radius_mm)
        s2 = 2.0 * self.sigma_mm ** 2
        return self.contrast * self.radius_mm / (r * self.sigma_mm * math.sqrt(2.0 * math.pi)) * (
            np.exp(-(self.radius_mm - r) ** 2 / s2) - np.exp(-(self.radius_mm + r) ** 2 / s2))


def fitted_ball(own_full: np.ndarray, fraction: np.ndarray, allowed: np.ndarray, spacing: np.ndarray,
                sl: tuple, reach_mm: float, unfitted: np.ndarray | None = None) -> Ball | None:
    """The blurred ball of one body (``own_full``, bounding slices ``sl``) fitted in ``allowed`` voxels
    (:func:`_fit_ball`); None where no filling surrounds it. ``unfitted``: voxels left out of the fit and
    of its misfit (silicone that is not the ball's: the base), where the ball may still be drawn."""
    from scipy import ndimage

    voxel = float(spacing.max())
    pad = int(np.ceil(LEVEL_VOXELS[1] * voxel / float(spacing.min()))) + 1
    box = tuple(slice(max(a.start - pad, 0), a.stop + pad) for a in sl)
    own, frac = own_full[box], fraction[box]
    outside = ndimage.distance_transform_edt(~own, sampling=spacing)
    inside = ndimage.distance_transform_edt(own, sampling=spacing)
    interior = own & (inside > voxel) if (own & (inside > voxel)).any() else own
    fitted = allowed[box] if unfitted is None else allowed[box] & ~unfitted[box]
    ring = fitted & (outside > LEVEL_VOXELS[0] * voxel) & (outside <= LEVEL_VOXELS[1] * voxel)
    if not ring.any():
        return None
    filling = float(np.median(frac[ring]))
    level = 0.5 * (float(np.median(frac[interior])) + filling)
    near = (outside <= PROFILE_VOXELS * voxel) & fitted
    body = own | ((outside <= reach_mm) & allowed[box] & (frac > level))
    origin = np.array([b.start for b in box], dtype=np.float64) * spacing
    points = np.argwhere(near) * spacing
    params = _fit_ball(frac[near], points, body, spacing, filling, 2 * (level - filling))
    misfit = math.inf
    if params is None:                               # no fit: the half-way level stands
        centre, radius, sigma, contrast = origin + np.argwhere(own).mean(axis=0) * spacing, 0.0, 0.0, 0.0
    else:
        centre, radius, sigma, contrast = origin + params[:3], params[3], params[4], params[5]
        level = filling + contrast * float(ball_profile(np.array([radius]), radius, sigma)[0])
        model = filling + contrast * ball_profile(np.linalg.norm(points - params[:3], axis=1), radius, sigma)
        noise = robust_sigma(frac[ring], filling)
        misfit = float(np.sqrt(np.mean((frac[near] - model) ** 2))) / max(noise, 1e-9)
    return Ball(centre, float(radius), float(sigma), float(contrast), filling, level, box,
                (outside <= reach_mm) & allowed[box], spacing, misfit)


def ball_profile(r_mm: np.ndarray, radius_mm: float, sigma_mm: float) -> np.ndarray:
    """A ball of ``radius_mm`` blurred by an isotropic Gaussian of ``sigma_mm``, at ``r_mm`` from its centre
    (0-1).

    At the ball's surface this is ``1/2 - sigma / (R sqrt(2 pi))`` for sigma << R: the half-way level of a
    flat boundary lies inside a curved one, by about ``sigma^2 / R``.
    """
    from scipy.special import erf

    r = np.maximum(np.asarray(r_mm, dtype=np.float64), 1e-6 * radius_mm)
    s = math.sqrt(2.0) * sigma_mm
    a, b = (radius_mm - r) / s, (radius_mm + r) / s
    return (0.5 * (erf(a) + erf(b)) - sigma_mm / (r * math.sqrt(2 * math.pi))
            * (np.exp(-a * a) - np.exp(-b * b)))


def _fit_ball(values: np.ndarray, points_mm: np.ndarray, body: np.ndarray, spacing: np.ndarray,
              filling: float, contrast: float) -> np.ndarray | None:
    """(centre (3), radius, blur, contrast over ``filling``) of a blurred ball fitted by least squares to
    ``values`` at ``points_mm`` (n, 3); None where too few values or no contrast.

    A compact body blurred by the scan and the denoising reads below half its contrast at its surface
    (:func:`ball_profile`), so the half-way level cuts a small inclusion too small; the blur is the
    scan's own, read from the body's profile. ``body``: its voxels (start of the fit).
    """
    from scipy.optimize import least_squares

    voxel = float(spacing.max())
    centre = np.argwhere(body).mean(axis=0) * spacing
    radius = (3.0 * float(body.sum()) * float(np.prod(spacing)) / (4 * math.pi)) ** (1 / 3)

    def residuals(p):
        r = np.linalg.norm(points_mm - p[:3], axis=1)
        return filling + p[5] * ball_profile(r, p[3], p[4]) - values

    lo = np.r_[centre - PROFILE_SHIFT_VOXELS * voxel, PROFILE_RADIUS[0] * radius,
               PROFILE_SIGMA_VOXELS[0] * voxel, PROFILE_CONTRAST[0] * contrast]
    hi = np.r_[centre + PROFILE_SHIFT_VOXELS * voxel, PROFILE_RADIUS[1] * radius,
               PROFILE_SIGMA_VOXELS[1] * voxel, PROFILE_CONTRAST[1] * contrast]
    if len(values) < len(lo) or contrast <= 0:
        return None
    start = np.clip(np.r_[centre, radius, 0.5 * voxel, contrast], lo, hi)
    return least_squares(residuals, start, bounds=(lo, hi)).x


def _column_ball(fraction, allowed, inc_ids, label, col: _Column, side: int, core_mm: float, step_mm: float,
                 spacing):
    """The inclusion's blurred ball, fitted away from other inclusions and from the column on the base side,
    from CAP_SHUT_VOXELS inside the body's end there: the post's silicone, blurred, reads within the ball's
    cap above it, and fitted with it, drew the ball's surface towards the post (by 0.1 mm over a 3 mm post
    1.2 mm tall at 0.95 mm voxels, whose radius, fitted below the ball, came out 0.08 mm short).

    Where the body runs on through a short post into the base (:func:`_run_on`), its own voxels past the
    other side's reach are not the ball's: taken as its, they put the base's silicone within the profile
    fitted, and the ball a fifth of a millimetre into the post."""
    from scipy import ndimage

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
