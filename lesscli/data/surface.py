"""The surface frame: contact onsets found from the forces, the surface fitted to them, poses put on it.

On a rig the phantom's top is not at the pose frame's zero: the phantom's height, the cast's thickness
and the calibration put it a millimetre or two away, and a little tilted. Every imager therefore takes
its poses in the *surface frame* found from the scan itself: per trajectory the contact onset, where the
total normal force passes a noise-scaled level (:func:`trajectory_onset`); per scan a robust plane
through the onsets (:func:`fit_surface`); each pose's z becomes its height above that plane, with roll
and pitch corrected by its slope (:func:`to_surface`). Every step is equivariant to a shift of z. The
onset height carries a bias of a fraction of a millimetre (the force is already above zero where it is
first seen), the same for training and imaging, so models learn it. :class:`OnlineSurface` keeps the
same rule for a live stream, from the touches seen so far.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lesscli.geometry.rotations import euler_to_matrix

ONSET_SIGMAS = 5.0          # onset level: this many standard deviations of the summed white noise
ONSET_SHARE = 0.05          # ... and at least this share of the trajectory's peak normal force
DEFAULT_NOISE_N = 0.01      # white noise per taxel, N, when the sensor file does not give noise_n
PLANE_MIN_ONSETS = 6        # fewer onsets: a flat surface at their median
PLANE_MIN_SPAN_MM = 5.0     # onsets spread less than this in x or y: flat
MAX_SLOPE = 0.2             # a fitted slope above this (11 deg) is not a phantom's top: flat
TRIM_SIGMAS = 3.0           # onsets this many robust spreads off the plane are left out of the next fit
TRIM_ROUNDS = 3
SPREAD_FLOOR_MM = 0.05      # robust spread never below this (exact synthetic onsets)
MAD_TO_SIGMA = 1.4826
FRAME = "surface"           # meta['pose_frame'] of a scan set whose poses are on its fitted surface


@dataclass
class Surface:
    """A plane ``z = a + b x + c y`` (mm) and the onsets behind it."""

    a_mm: float = 0.0
    b: float = 0.0
    c: float = 0.0
    onsets: int = 0

    def height_mm(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        return self.a_mm + self.b * np.asarray(x_mm, np.float64) + self.c * np.asarray(y_mm, np.float64)

    def to_dict(self) -> dict:
        return {"a_mm": round(self.a_mm, 4), "b": round(self.b, 5), "c": round(self.c, 5),
                "onsets": self.onsets}


def pad_half_size(sensor: dict) -> tuple[float, float]:
    """Half the pad face's width and height (mm), from ``pad_size_mm`` or the taxel extent plus a pitch."""
    size = sensor.get("pad_size_mm")
    if not size:
        xy = np.asarray(sensor.get("taxel_xy_mm") or [[0.0, 0.0]], np.float64).reshape(-1, 2)
        size = np.ptp(xy, axis=0) + float(sensor.get("pitch_mm", 0.0))
    return float(size[0]) / 2, float(size[1]) / 2


def lowest_point(pose: np.ndarray, half: tuple[float, float]) -> np.ndarray:
    """(n, 6) poses -> (n, 3) x, y, z of the lowest corner of the pad face."""
    pose = np.asarray(pose, np.float64).reshape(-1, 6)
    w, h = half
    corners = np.array([[-w, -h], [w, -h], [w, h], [-w, h]])
    rot = euler_to_matrix(pose[:, 3:])
    pts = pose[:, None, :3] + np.einsum("nij,kj->nki", rot[:, :, :2], corners)
    return pts[np.arange(len(pose)), pts[..., 2].argmin(axis=1)]


def onset_level(normal: np.ndarray, taxels: int, noise_n: float) -> float:
    """The force a trajectory's total normal force must pass to count as contact.

    ``max(ONSET_SIGMAS * noise_n * sqrt(T), ONSET_SHARE * max N)``, with ``noise_n`` the sensor's white
    noise per taxel in the scan set's force units (:func:`sensor_noise_n`) and T taxels.
    """
    peak = float(normal.max()) if len(normal) else 0.0
    return max(ONSET_SIGMAS * noise_n * np.sqrt(taxels), ONSET_SHARE * peak)


def trajectory_onset(low: np.ndarray, normal: np.ndarray, level: float) -> np.ndarray | None:
    """(3,) x, y, z of the contact onset of one trajectory, or None when the force never passes ``level``.

    The first step above the level is the onset step; the contact height is where the force, extrapolated
    linearly through that step and the next deeper one of the loading branch, reaches zero (clamped between
    the onset step and the step before it), read at the pad's lowest corner (a tilted pad touches with its
    lowest point first). Sparse (subsampled) scans keep working: the extrapolation does not need the step
    before contact to lie close to the surface. Trajectories start out of contact (as the published
    preprocessing trims them), so the normal force is taken less its first sample.

    Args:
        low: (n, 3) lowest pad point per step.
        normal: (n,) total normal force, less the first sample.
        level: onset level (:func:`onset_level`).
    """
    above = np.flatnonzero(normal > level)
    if not len(above) or above[0] == 0:
        return None
    i = int(above[0])
    z = low[i, 2]
    deeper = np.flatnonzero((low[i + 1:, 2] < z) & (normal[i + 1:] > normal[i]))
    if len(deeper):
        j = i + 1 + int(deeper[0])
        z = z + (z - low[j, 2]) * normal[i] / (normal[j] - normal[i])
    z = float(np.clip(z, low[i, 2], max(low[i, 2], low[i - 1, 2])))
    return np.array([low[i, 0], low[i, 1], z])


def fit_surface(onsets: np.ndarray) -> Surface:
    """A robust plane (or flat surface) through (n, 3) onset points.

    ``h(x, y) = a + b x + c y`` by least squares, refitted ``TRIM_ROUNDS`` times without the onsets more
    than ``TRIM_SIGMAS`` robust spreads off it (a touch that slid in, or started in contact, does not move
    it). With fewer than ``PLANE_MIN_ONSETS`` onsets, onsets spread over less than ``PLANE_MIN_SPAN_MM``, or
    a slope above ``MAX_SLOPE``, the surface is flat at the onsets' median; no onset keeps the frame's zero.
    """
    onsets = np.asarray(onsets, np.float64).reshape(-1, 3)
    n = len(onsets)
    if n == 0:
        return Surface()
    flat = Surface(float(np.median(onsets[:, 2])), 0.0, 0.0, n)
    span = np.ptp(onsets[:, :2], axis=0)
    if n < PLANE_MIN_ONSETS or span.min() < PLANE_MIN_SPAN_MM:
        return flat
    design = np.c_[np.ones(n), onsets[:, :2] - onsets[:, :2].mean(axis=0)]
    keep = np.ones(n, bool)
    for _ in range(TRIM_ROUNDS):
        if keep.sum() < PLANE_MIN_ONSETS:
            return flat
        coef = np.linalg.lstsq(design[keep], onsets[keep, 2], rcond=None)[0]
        resid = onsets[:, 2] - design @ coef
        spread = max(MAD_TO_SIGMA * float(np.median(np.abs(resid[keep] - np.median(resid[keep])))),
                     SPREAD_FLOOR_MM)
        keep = np.abs(resid) <= TRIM_SIGMAS * spread
    if max(abs(coef[1]), abs(coef[2])) > MAX_SLOPE:
        return flat
    centre = onsets[:, :2].mean(axis=0)
    return Surface(float(coef[0] - coef[1] * centre[0] - coef[2] * centre[1]), float(coef[1]), float(coef[2]),
                   n)


def to_surface(pose: np.ndarray, surf: Surface) -> np.ndarray:
    """(n, 6) poses -> the same poses in the frame of ``surf``: z above it, roll and pitch corrected by its
    slope to first order, so every taxel's depth below the surface is right for a tilted top too."""
    pose = np.asarray(pose, np.float64).reshape(-1, 6)
    out = pose.copy()
    out[:, 2] = pose[:, 2] - surf.height_mm(pose[:, 0], pose[:, 1])
    if surf.b or surf.c:
        rot = euler_to_matrix(pose[:, 3:])
        r20 = rot[:, 2, 0] - surf.b * rot[:, 0, 0] - surf.c * rot[:, 1, 0]
        r21 = rot[:, 2, 1] - surf.b * rot[:, 0, 1] - surf.c * rot[:, 1, 1]
        pitch = -np.arcsin(np.clip(r20, -1.0, 1.0))
        out[:, 4] = pitch
        out[:, 3] = np.arcsin(np.clip(r21 / np.cos(pitch), -1.0, 1.0))
    return out


def sensor_noise_n(meta: dict) -> float:
    """White noise per taxel in the scan set's force units (the sensor file's ``noise_n``, else the default
    scaled by ``counts_per_n`` for a scan set in counts)."""
    sensor = meta.get("sensor") or {}
    if sensor.get("noise_n") is not None:
        return float(sensor["noise_n"])
    units = (meta.get("units") or {}).get("force", "N")
    return DEFAULT_NOISE_N * (float(sensor.get("counts_per_n") or 1.0) if units == "counts" else 1.0)


def scan_onsets(pose: np.ndarray, force: np.ndarray, bounds: np.ndarray, half: tuple[float, float],
                noise_n: float) -> np.ndarray:
    """(k, 3) onsets of the trajectories ``[bounds[r], bounds[r+1])`` of one scan's steps."""
    low = lowest_point(pose, half)
    normal = force[..., 2].astype(np.float64).sum(axis=1)
    taxels = force.shape[1]
    found = []
    for r in range(len(bounds) - 1):
        a, b = int(bounds[r]), int(bounds[r + 1])
        if b - a < 2:
            continue
        rel = normal[a:b] - normal[a]
        onset = trajectory_onset(low[a:b], rel, onset_level(rel, taxels, noise_n))
        if onset is not None:
            found.append(onset)
    return np.asarray(found, np.float64).reshape(-1, 3)


def surfaces(scans) -> list[Surface]:
    """The fitted surface of every scan of a :class:`~lesscli.io.scans.ScanSet`."""
    half, noise = pad_half_size(scans.meta.get("sensor") or {}), sensor_noise_n(scans.meta)
    toff, out = scans.scan_traj_offsets(), []
    for s in range(scans.n_scans):
        sl = scans.scan_steps(s)
        bounds = scans.traj_offsets[toff[s]:toff[s + 1] + 1] - sl.start
        out.append(fit_surface(scan_onsets(scans.pose[sl], scans.force[sl], bounds, half, noise)))
    return out


def surface_frame(scans):
    """The scan set with every pose in its scan's surface frame (``meta['pose_frame'] = 'surface'``, the
    fitted planes in ``meta['surface']``); a set already there is returned as it is."""
    if scans.meta.get("pose_frame") == FRAME:
        return scans
    pose = np.array(scans.pose, np.float64)
    fitted = surfaces(scans)
    for s, surf in enumerate(fitted):
        sl = scans.scan_steps(s)
        pose[sl] = to_surface(pose[sl], surf)
    meta = {**scans.meta, "pose_frame": FRAME, "surface": [f.to_dict() for f in fitted]}
    return replace(scans, pose=pose.astype(scans.pose.dtype), meta=meta)


class OnlineSurface:
    """The same rule for a live stream, touch by touch. A touch begins with a sample out of contact (its
    force is the touch's baseline) and ends when its force, having passed the noise part of the onset
    level (``ONSET_SIGMAS * noise_n * sqrt(T)``), falls back below it (the pad lifted off), or when a
    sample's time restarts below the previous one (a replayed trajectory). At its end the touch's onset
    is found as in batch and the surface refitted over every onset so far; poses are put on the current
    surface as they arrive. Until the first touch has ended, the surface is flat at the lowest pad point
    of the first sample above the noise level (before that, the frame's zero: nothing has been touched).

    Args:
        sensor: the checkpoint's sensor table (``pad_size_mm`` / ``taxel_xy_mm``, ``noise_n``).
        taxels: T.
    """

    def __init__(self, sensor: dict, taxels: int, noise_n: float | None = None) -> None:
        self.half = pad_half_size(sensor)
        self.taxels = taxels
        self.noise_n = float(sensor.get("noise_n") or DEFAULT_NOISE_N) if noise_n is None else noise_n
        self.noise_level = ONSET_SIGMAS * self.noise_n * np.sqrt(taxels)
        self.surface = Surface()
        self.onsets: list[np.ndarray] = []
        self._low: list[np.ndarray] = []
        self._normal: list[float] = []
        self._last_t: float | None = None
        self._touching = False

    def _close(self) -> None:
        if len(self._low) >= 2:
            normal = np.asarray(self._normal) - self._normal[0]
            onset = trajectory_onset(np.asarray(self._low), normal,
                                     onset_level(normal, self.taxels, self.noise_n))
            if onset is not None:
                self.onsets.append(onset)
                self.surface = fit_surface(np.asarray(self.onsets))
        self._low, self._normal, self._touching = [], [], False

    def push(self, pose: np.ndarray, force: np.ndarray, t: float | None = None) -> np.ndarray:
        """One raw sample -> its pose (6,) in the current surface frame."""
        if t is not None and self._last_t is not None and t < self._last_t:
            self._close()
        self._last_t = t
        low = lowest_point(pose, self.half)[0]
        normal = float(np.asarray(force, np.float64).reshape(self.taxels, 3)[:, 2].sum())
        if self._normal and normal - self._normal[0] > self.noise_level:
            if not self._touching and not self.onsets:
                # provisional: the first touch's onset
                self.surface = Surface(float(low[2]), 0.0, 0.0, 0)
            self._touching = True
        elif self._touching:
            # lifted off: this sample starts the next
            self._close()
        self._low.append(low)
        self._normal.append(normal)
        return to_surface(pose, self.surface)[0]
