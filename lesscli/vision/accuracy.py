"""Pose accuracy against a reference stream, as the paper's appendix "Pose Estimation Accuracy" defines it.

The reference (robot kinematics or rendered truth) is interpolated to the tracked timestamps (linear
position, SLERP rotation). With per-axis errors e_i = (e_ix, e_iy, e_iz) over N synchronised poses,

    sigma = sqrt( 1 / (3 N) * sum_i (e_ix^2 + e_iy^2 + e_iz^2) )

for positions (mm) and for angles (rad). Angular errors are the components of the rotation vector of
``R_ref^T R_est`` (the error rotation in the reference's own frame).
"""

from __future__ import annotations

import numpy as np

from lesscli.errors import DataError
from lesscli.geometry import rotations
from lesscli.vision.calibrate import Calibration
from lesscli.vision.streams import PoseStream, sync

AXES = ("x", "y", "z")


def pose_errors(est: PoseStream, ref: PoseStream, calibration: Calibration | None = None) -> dict:
    """Per-sample errors of ``est`` against ``ref`` after an optional calibration.

    Returns:
        dict with ``time_s`` (N,), ``position_mm`` (N, 3) and ``angle_rad`` (N, 3) per-axis errors.
    """
    if calibration is not None:
        est = calibration.apply(est)
    kept, matched = sync(est, ref, 0.0)
    if len(kept) == 0:
        raise DataError(f"accuracy: no tracked pose lies inside the reference's time span "
                        f"({ref.time_s[0] if len(ref) else float('nan'):.3f}.."
                        f"{ref.time_s[-1] if len(ref) else float('nan'):.3f} s)")
    ang = rotations.matrix_to_rotvec(np.swapaxes(matched.rotation, 1, 2) @ kept.rotation)
    return {"time_s": kept.time_s, "position_mm": kept.position_mm - matched.position_mm, "angle_rad": ang}


def sigma(errors: np.ndarray) -> float:
    """sqrt(sum of squared per-axis errors / (3 N)) for (N, 3) errors."""
    return float(np.sqrt(np.sum(np.square(errors)) / (3 * len(errors))))


def summarize(errors: dict, n_tracked: int) -> dict:
    """One record: sigma_positional/sigma_angular, per-axis RMS and bias, medians and maxima."""
    pos, ang = errors["position_mm"], errors["angle_rad"]
    pos_norm, ang_norm = np.linalg.norm(pos, axis=1), np.linalg.norm(ang, axis=1)
    row = {"n_poses": len(pos), "n_skipped": n_tracked - len(pos),
           "sigma_positional_mm": sigma(pos), "sigma_angular_rad": sigma(ang)}
    for k, axis in enumerate(AXES):
        row[f"rms_{axis}_mm"] = float(np.sqrt(np.mean(pos[:, k] ** 2)))
    for k, axis in enumerate(AXES):
        row[f"rms_{axis}_rad"] = float(np.sqrt(np.mean(ang[:, k] ** 2)))
    for k, axis in enumerate(AXES):
        row[f"bias_{axis}_mm"] = float(np.mean(pos[:, k]))
    row.update({"median_position_error_mm": float(np.median(pos_norm)),
                "max_position_error_mm": float(pos_norm.max()),
                "median_angle_error_deg": float(np.rad2deg(np.median(ang_norm))),
                "max_angle_error_deg": float(np.rad2deg(ang_norm.max()))})
    return row


def plot_errors(errors: dict, path: str, title: str = "pose error") -> None:
    """PNG of per-axis position (mm) and angle (deg) errors over time (written atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lesscli.io.atomic import atomic_path

    t = errors["time_s"] - errors["time_s"][0]
    fig, (ax_p, ax_a) = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
    for k, axis in enumerate(AXES):
        ax_p.plot(t, errors["position_mm"][:, k], lw=1, label=axis)
        ax_a.plot(t, np.rad2deg(errors["angle_rad"][:, k]), lw=1, label=axis)
    ax_p.set_ylabel("position error (mm)")
    ax_a.set_ylabel("angle error (deg)")
    ax_a.set_xlabel("time (s)")
    ax_p.set_title(f"{title}: sigma_pos {sigma(errors['position_mm']):.3f} mm, "
                   f"sigma_ang {sigma(errors['angle_rad']):.4f} rad")
    for ax in (ax_p, ax_a):
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    try:
        with atomic_path(path, ".png") as tmp:
            fig.savefig(tmp, dpi=120, format="png")
    finally:
        plt.close(fig)
