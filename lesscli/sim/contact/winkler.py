"""Tier 0 ``winkler``: column springs over the layered body, blurred, with one calibrated gain.

Each surface point (x, y) is a spring of stiffness per area k(x, y) with
1/k = integral_{-H}^{0} dz / E(x, y, z) (N/mm^3). The stiffness map is blurred with a Gaussian
(a Pasternak-like shear coupling: a buried inclusion is felt over a lateral distance comparable to
its depth), and the pressure is p = gain * k_blur * penetration. The gain matches the flat-punch
closed form of a homogeneous body, F = 1.13 E* sqrt(A) d = gain * (E / H) * A * d, times ``gain_scale``
(1.75: the ratio of tier 2 to that closed form on the default 60 x 30 mm insert). A bounded flat-punch
profile over the pad (``rim``) puts more pressure under its rim, as tier 2 does.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from lesscli.errors import SimulationError
from lesscli.geometry.rotations import euler_to_matrix
from lesscli.sim import kinematics
from lesscli.sim.contact.base import ContactModel, check_params
from lesscli.sim.fem import KPA_TO_N_MM2, NU_MAX

FLAT_PUNCH_COEF = 1.13        # F = 1.13 E* sqrt(A) d for a flat punch on a half-space
RIM_EPS = 0.05                # bounds the rim profile (the sensor skin's role in tier 2)
GROUP_MIN = 8                 # steps per distinct pad placement above which steps are solved per placement
DEFAULTS = {"grid_mm": 0.5, "z_samples": 60, "blur_mm": 3.0, "sub": 4, "gain": None,
            "gain_scale": 1.75, "nu": None, "rim": 1.0}


def outline_radius_mm(phantom) -> float:
    """Largest distance of the outline from the origin, mm."""
    if hasattr(phantom, "outline_xy"):
        return float(np.max(np.linalg.norm(np.asarray(phantom.outline_xy()), axis=1)))
    return float(phantom.width_mm) / 2 / math.cos(math.pi / 8)


def phantom_nu(phantom, nu: float | None = None) -> float:
    """Poisson's ratio used by the tiers: the filling's (default 0.45), capped at ``NU_MAX``."""
    if nu is None:
        nu = getattr(getattr(phantom, "filling", None), "poisson", NU_MAX)
    return min(float(nu), NU_MAX)


class WinklerContact(ContactModel):
    """Tier 0: column springs + blur + one gain; 10-100 us per step, vectorised over steps."""

    name = "winkler"

    def __init__(self, phantom, sensor: dict | None = None, **params) -> None:
        super().__init__(phantom, sensor, **check_params(self.name, params, DEFAULTS))

    def prepare(self, cache_dir: str | None = None) -> None:
        """Build the blurred column-stiffness map (fast; ``cache_dir`` is not needed)."""
        from scipy.ndimage import gaussian_filter

        if self._prepared:
            return
        ph, h = self.phantom, float(self.params["grid_mm"])
        n = math.ceil((outline_radius_mm(ph) + 2 * h) / h)
        self.axis_mm = h * np.arange(-n, n + 1)
        x, y = np.meshgrid(self.axis_mm, self.axis_mm, indexing="xy")      # (ny, nx)
        self.inside = np.asarray(ph.inside_outline(x, y), dtype=bool)
        self.k_raw = self._column_stiffness(x, y)
        sigma = float(self.params["blur_mm"]) / h
        self.k_map = gaussian_filter(self.k_raw, sigma, mode="constant") if sigma > 0 else self.k_raw.copy()
        self.k_map[~self.inside] = 0.0
        self.points, self.owner, self.cell_area = self.pad.cell_samples(int(self.params["sub"]))
        self.rim = self._rim_weights()
        self.gain = self._gain()
        self._prepared = True

    def _column_stiffness(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(ny, nx) k = 1 / integral dz / E, N/mm^3; 0 outside the outline."""
        height, nz = float(self.phantom.height_mm), int(self.params["z_samples"])
        dz = height / nz
        inv_k = np.zeros(x.shape)
        xi, yi = x[self.inside], y[self.inside]
        acc = np.zeros(xi.size)
        for z in -height + dz * (np.arange(nz) + 0.5):
            e = np.asarray(self.phantom.youngs_kpa(np.stack([xi, yi, np.full(xi.size, z)], 1)), dtype=float)
            if (e <= 0).any() or not np.isfinite(e).all():
                raise SimulationError(f"contact 'winkler': Young's modulus not positive inside the outline "
                                      f"at z = {z:.2f} mm")
            acc += dz / (e * KPA_TO_N_MM2)
        inv_k[self.inside] = acc
        k = np.zeros(x.shape)
        k[self.inside] = 1.0 / inv_k[self.inside]
        return k

    def _rim_weights(self) -> np.ndarray:
        """(M,) flat-punch pressure profile over the pad, mean 1 (``rim`` = 0: uniform).

        A rigid flat punch presses hardest at its rim (p ~ 1/sqrt(1 - s^2) across each side); the
        sensor skin bounds the peak. ``rim`` in [0, 1] blends that profile with a uniform one.
        """
        rim = float(self.params["rim"])
        prof = np.ones(self.points.shape[0])
        for axis in range(2):
            s = self.points[:, axis] / self.pad.half_size_mm[axis]
            prof *= 1.0 / np.sqrt(np.maximum(1.0 - s ** 2, 0.0) + RIM_EPS)
        prof /= prof.mean()
        return (1.0 - rim) + rim * prof

    def _gain(self) -> float:
        """The flat-punch calibration gain (or the ``gain`` parameter)."""
        if self.params["gain"] is not None:
            return float(self.params["gain"])
        nu = phantom_nu(self.phantom, self.params["nu"])
        coef = FLAT_PUNCH_COEF * float(self.phantom.height_mm) / ((1 - nu ** 2)
                                                                  * math.sqrt(self.pad.area_mm2))
        return coef * float(self.params["gain_scale"])

    def stiffness_at(self, xy_mm: np.ndarray) -> np.ndarray:
        """(..., 2) -> (...) blurred column stiffness, bilinear, 0 off the map."""
        from scipy.ndimage import map_coordinates

        h, x0 = float(self.params["grid_mm"]), self.axis_mm[0]
        coords = np.stack([(xy_mm[..., 1].ravel() - x0) / h, (xy_mm[..., 0].ravel() - x0) / h])
        out = map_coordinates(self.k_map, coords, order=1, mode="constant", cval=0.0, prefilter=False)
        return out.reshape(xy_mm.shape[:-1])

    def _normal(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # Consecutive steps that share the pad's placement (x, y, roll, pitch, yaw) and differ only in z
        # -- every step of a vertical press -- share the stiffness lookups; only the penetration is per step.
        key = pose[:, [0, 1, 3, 4, 5]]
        starts = np.concatenate([[0], np.nonzero(np.any(key[1:] != key[:-1], axis=1))[0] + 1, [len(key)]])
        # run of equal consecutive placements
        inverse = np.repeat(np.arange(starts.size - 1), np.diff(starts))
        flat = np.zeros((starts.size - 1, 6))
        flat[:, [0, 1, 3, 4, 5]] = key[starts[:-1]]
        world = kinematics.pad_to_world(flat, self.points)                 # (u, M, 3) at z = 0
        cos_t = euler_to_matrix(flat[:, 3:])[:, 2, 2]
        # vertical force per sample on its horizontal area, projected onto the pad normal
        weight = self.gain * self.stiffness_at(world[..., :2]) * (self.cell_area
                                                                  * cos_t[:, None] ** 2) * self.rim
        n = pose.shape[0]
        normal, indent, overhang = np.zeros((n, self.pad.taxels)), np.zeros(n), np.zeros(n, dtype=bool)
        if flat.shape[0] * GROUP_MIN > n:                                   # few steps per placement
            normal[:], indent[:], overhang[:] = self._samples(pose[:, 2], world[inverse, :, 2],
                                                              weight[inverse])
        else:
            for g, (a, b) in enumerate(itertools.pairwise(starts)):
                normal[a:b], indent[a:b], overhang[a:b] = self._press(pose[a:b, 2], world[g, :, 2], weight[g])
        c_pen, c_out = self.corner_penetration(pose)
        return normal, np.maximum(indent, c_pen), overhang | c_out

    def _samples(self, z: np.ndarray, c: np.ndarray, w: np.ndarray):
        """Per-sample evaluation: z (k,), sample heights at z = 0 c (k, M), weights w (k, M)."""
        pen = np.maximum(-(z[:, None] + c), 0.0)
        normal = (w * pen).reshape(z.size, self.pad.taxels, -1).sum(axis=2)   # samples grouped by taxel
        inside = w > 0                                                         # the map is 0 off the outline
        return normal, np.where(inside, pen, 0.0).max(axis=1), ((pen > 0) & ~inside).any(axis=1)

    def _press(self, z: np.ndarray, c: np.ndarray, w: np.ndarray):
        """Steps of one placement: taxels fully in contact are linear in z; others go per sample."""
        t = self.pad.taxels
        cw, ww = c.reshape(t, -1), w.reshape(t, -1)
        inside = w > 0
        c_in = c[inside].min(initial=np.inf)
        c_out = c[~inside].min(initial=np.inf)
        indent = np.maximum(-(z + c_in), 0.0) if np.isfinite(c_in) else np.zeros(z.size)
        overhang = (z + c_out < 0) if np.isfinite(c_out) else np.zeros(z.size, dtype=bool)
        full = z[:, None] + cw.max(axis=1) <= 0
        normal = np.where(full, -(z[:, None] * ww.sum(axis=1) + (ww * cw).sum(axis=1)), 0.0)
        partial = (~full & (z[:, None] + cw.min(axis=1) < 0)).any(axis=1)
        if partial.any():
            k = int(partial.sum())
            normal[partial] = self._samples(z[partial], np.broadcast_to(c, (k, c.size)),
                                            np.broadcast_to(w, (k, w.size)))[0]
        return normal, indent, overhang
