"""Calibrate tracked poses to the robot frame: time offset, Kabsch inside RANSAC, orientation offset.

Model: ``p_robot = r_pos p_est + t_pos`` (rows: ``p <- p r_pos^T + t_pos``) and
``R_robot = R_pre R_est R_ori`` with ``R_pre = r_pos`` (the frame change rotates orientations too) and
``R_ori`` the fixed rotation from the tracked sensor frame to the robot's end-effector frame. The
published layout (``r_pos``, ``t_pos``, ``R_ori``, applied as ``R <- R R_ori``) is what files without
``R_pre`` mean, i.e. ``R_pre`` defaults to the identity. The robot sample at ``t + time_offset_s``
belongs to the tracked sample at ``t``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from lesscli.errors import DataError
from lesscli.geometry import rotations
from lesscli.io.atomic import atomic_path
from lesscli.io.npfiles import read_npz
from lesscli.io.scans import append_history
from lesscli.vision.streams import PoseStream, sync

SCHEMA = "less.posecal/1"
COLLINEAR_RATIO = 1e-3      # second/first singular value of the centred points below this: collinear
MIN_POINTS = 3
MIN_PAIRS = 10              # synchronised pairs needed for a calibration
PAIR_SAMPLES = 4000         # random point pairs for the rigid-invariant time-offset score


@dataclass
class Calibration:
    r_pos: np.ndarray                 # (3, 3)
    t_pos: np.ndarray                 # (3,) mm
    R_ori: np.ndarray                 # (3, 3)
    R_pre: np.ndarray                 # (3, 3); identity for the published layout
    time_offset_s: float = 0.0
    inlier_fraction: float = float("nan")
    rmse_mm: float = float("nan")

    def apply(self, stream: PoseStream) -> PoseStream:
        """Map a tracked stream into the robot frame and clock."""
        return PoseStream(stream.time_s + self.time_offset_s, stream.position_mm @ self.r_pos.T + self.t_pos,
                          self.R_pre @ stream.rotation @ self.R_ori)


def check_spread(points: np.ndarray, name: str = "calibration") -> None:
    """Raise DataError if fewer than 3 points or all on one line (the rotation would be undetermined)."""
    if len(points) < MIN_POINTS:
        raise DataError(f"{name}: {len(points)} point pairs; Kabsch needs at least {MIN_POINTS}")
    sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if sv[0] <= 0 or sv[1] / sv[0] < COLLINEAR_RATIO:
        raise DataError(f"{name}: all points lie on one line; the rotation about it is undetermined "
                        "(move the sensor in at least two directions)")


def kabsch(src: np.ndarray, dst: np.ndarray,
           weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rigid fit without reflection or scale: ``dst ~ src R^T + t``.

    Args:
        src, dst: (n, 3) corresponding points, mm.
        weights: optional (n,) non-negative weights.

    Returns:
        R (3, 3) with det +1 and t (3,).
    """
    w = np.ones(len(src)) if weights is None else np.asarray(weights, np.float64)
    w = w / w.sum()
    cs, cd = w @ src, w @ dst
    cov = (dst - cd).T @ ((src - cs) * w[:, None])
    rot = rotations.project_to_so3(cov)
    return rot, cd - rot @ cs


def ransac_kabsch(src: np.ndarray, dst: np.ndarray, rng: np.random.Generator, threshold_mm: float = 3.0,
                  iterations: int = 300) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kabsch inside RANSAC: minimal non-collinear triples, consensus by residual, refit on inliers.

    Returns:
        R (3, 3), t (3,), inliers (n,) bool.
    """
    check_spread(src, "calibration (tracked positions)")
    n = len(src)
    best = np.zeros(n, bool)
    for _ in range(iterations):
        idx = rng.choice(n, size=3, replace=False)
        tri = src[idx]
        if np.linalg.norm(np.cross(tri[1] - tri[0], tri[2] - tri[0])) < 1e-6:
            continue
        rot, t = kabsch(tri, dst[idx])
        inl = np.linalg.norm(src @ rot.T + t - dst, axis=1) < threshold_mm
        if inl.sum() > best.sum():
            best = inl
    if best.sum() < MIN_POINTS:
        raise DataError(f"calibration: no consensus within {threshold_mm} mm (raise --threshold-mm?)")
    for _ in range(3):
        check_spread(src[best], "calibration (inliers)")
        rot, t = kabsch(src[best], dst[best])
        best = np.linalg.norm(src @ rot.T + t - dst, axis=1) < threshold_mm
    return rot, t, best


def _pair_score(est: PoseStream, ref: PoseStream, offset_s: float, pairs: np.ndarray) -> float:
    """Median mismatch of point-pair distances (rigid-invariant, robust) at one time offset."""
    kept, matched = sync(est, ref, offset_s)
    if len(kept) < MIN_PAIRS:
        return float("inf")
    i, j = pairs[:, 0] % len(kept), pairs[:, 1] % len(kept)
    d_est = np.linalg.norm(kept.position_mm[i] - kept.position_mm[j], axis=1)
    d_ref = np.linalg.norm(matched.position_mm[i] - matched.position_mm[j], axis=1)
    return float(np.median(np.abs(d_est - d_ref)))


def estimate_time_offset(est: PoseStream, ref: PoseStream, max_offset_s: float, rng: np.random.Generator,
                         step_s: float | None = None) -> float:
    """Time offset in [-max, max] that best aligns the streams (coarse grid, then finer grids).

    Pairwise distances do not change under the unknown rigid transform, so the offset is found before
    the transform, and the median makes outliers harmless.
    """
    if max_offset_s <= 0:
        return 0.0
    pairs = rng.integers(0, 2**31 - 1, size=(PAIR_SAMPLES, 2))
    dt = float(np.median(np.diff(est.time_s))) if len(est) > 1 else 0.01
    step = step_s or max(dt / 2.0, 1e-3)
    centre, half = 0.0, max_offset_s
    for _ in range(4):
        grid = np.arange(centre - half, centre + half + step / 2, step)
        grid = grid[np.abs(grid) <= max_offset_s + 1e-12]
        scores = np.array([_pair_score(est, ref, float(o), pairs) for o in grid])
        if not np.isfinite(scores).any():
            raise DataError("calibration: the two streams do not overlap in time at any offset "
                            f"within +-{max_offset_s} s")
        centre = float(grid[int(np.argmin(scores))])
        half, step = 2 * step, step / 5
    return centre


def calibrate(est: PoseStream, ref: PoseStream, rng: np.random.Generator, threshold_mm: float = 3.0,
              max_offset_s: float = 0.5, time_offset_s: float | None = None,
              iterations: int = 300) -> Calibration:
    """Fit the calibration of ``est`` (tracked) onto ``ref`` (robot).

    Args:
        est, ref: pose streams (see lesscli.vision.streams).
        rng: random generator for RANSAC and the offset search.
        threshold_mm: RANSAC inlier distance.
        max_offset_s: search the time offset within +-this (0: assume synchronised clocks).
        time_offset_s: a known offset (skips the search).
        iterations: RANSAC iterations.
    """
    if len(est) < MIN_POINTS or len(ref) < 2:
        raise DataError(f"calibration: {len(est)} tracked and {len(ref)} robot poses; need at least "
                        f"{MIN_POINTS} and 2")
    slack = max_offset_s if time_offset_s is None else 0.0
    shift = 0.0 if time_offset_s is None else time_offset_s
    if est.time_s[0] + shift - slack > ref.time_s[-1] or est.time_s[-1] + shift + slack < ref.time_s[0]:
        raise DataError(f"calibration: no time overlap (tracked {est.time_s[0]:.3f}..{est.time_s[-1]:.3f} s, "
                        f"robot {ref.time_s[0]:.3f}..{ref.time_s[-1]:.3f} s, offset {shift:+.3f} +- {slack} "
                        "s)")
    offset = time_offset_s if time_offset_s is not None else estimate_time_offset(est, ref, max_offset_s, rng)
    kept, matched = sync(est, ref, offset)
    if len(kept) < MIN_POINTS:
        raise DataError(f"calibration: only {len(kept)} tracked poses overlap the robot's time span")
    rot, t, inl = ransac_kabsch(kept.position_mm, matched.position_mm, rng, threshold_mm, iterations)
    rotated = rot @ kept.rotation[inl]
    r_ori = rotations.project_to_so3(np.sum(np.swapaxes(rotated, 1, 2) @ matched.rotation[inl], axis=0))
    resid = np.linalg.norm(kept.position_mm[inl] @ rot.T + t - matched.position_mm[inl], axis=1)
    return Calibration(rot, t, r_ori, rot.copy(), float(offset), float(inl.mean()),
                       float(np.sqrt(np.mean(resid**2))))


def save_calibration(path: str, cal: Calibration, seed: int | None = None) -> None:
    """Write the published layout plus ``R_pre``, ``time_offset_s`` and a ``meta`` JSON (atomic)."""
    meta = append_history({"schema": SCHEMA, "units": {"t_pos": "mm", "time_offset_s": "s"},
                           "model": "p <- p r_pos^T + t_pos; R <- R_pre R R_ori; t <- t + time_offset_s",
                           "inlier_fraction": cal.inlier_fraction, "rmse_mm": cal.rmse_mm}, seed=seed)
    with atomic_path(path, ".npz") as tmp:
        np.savez(tmp, r_pos=cal.r_pos, t_pos=cal.t_pos, R_ori=cal.R_ori, R_pre=cal.R_pre,
                 time_offset_s=np.float64(cal.time_offset_s), meta=np.array(json.dumps(meta)))


def load_calibration(path: str) -> Calibration:
    """Read a calibration; files with only ``r_pos``, ``t_pos``, ``R_ori`` (published) get R_pre = I."""
    arrays = read_npz(path, what="calibration")
    shapes = {"r_pos": (3, 3), "t_pos": (3,), "R_ori": (3, 3)}
    for key, shape in shapes.items():
        if key not in arrays:
            raise DataError(f"{path}: missing '{key}' (a calibration holds r_pos (3x3), t_pos (3,), R_ori "
                            "(3x3))")
        if np.asarray(arrays[key]).shape != shape:
            raise DataError(f"{path}: '{key}' has shape {np.asarray(arrays[key]).shape}, expected {shape}")
    vals = {k: np.asarray(arrays[k], np.float64) for k in shapes}
    r_pre = np.asarray(arrays.get("R_pre", np.eye(3)), np.float64)
    for key, mat in (("r_pos", vals["r_pos"]), ("R_ori", vals["R_ori"]), ("R_pre", r_pre)):
        if mat.shape != (3, 3) or not np.isfinite(mat).all() or np.abs(mat.T @ mat - np.eye(3)).max() > 1e-4 \
                or np.linalg.det(mat) < 0:
            raise DataError(f"{path}: '{key}' is not a rotation matrix")
    if not np.isfinite(vals["t_pos"]).all():
        raise DataError(f"{path}: 't_pos' is not finite")
    offset = float(np.asarray(arrays.get("time_offset_s", 0.0)))
    return Calibration(vals["r_pos"], vals["t_pos"], vals["R_ori"], r_pre, offset)


def apply_to_pose6(pose: np.ndarray, cal: Calibration) -> np.ndarray:
    """Apply a calibration to scan-set poses (n, 6) = x, y, z mm, roll, pitch, yaw rad (Rz Ry Rx)."""
    pose = np.asarray(pose, np.float64)
    pos = pose[:, :3] @ cal.r_pos.T + cal.t_pos
    rot = cal.R_pre @ rotations.euler_to_matrix(pose[:, 3:]) @ cal.R_ori
    return np.concatenate([pos, rotations.matrix_to_euler(rot)], axis=1)
