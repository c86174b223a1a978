"""``less bench pose``: sensor-pose error and time per frame of the tracking variants on rendered frames.

One rendered set (1280x720, f = 900 px, tags 0.35-0.7 m away, tilts within 35 degrees, blur and noise)
is tracked by each variant; the baseline is the plain pipeline (``--refine apriltag`` corners with the
half-pixel correction, no edge fit, the global tag solved per frame). Rows give the median and 90th
percentile position (mm) and angle (deg) errors of the sensor in the global tag's frame, the seconds
per frame, and ratios of the median errors against the baseline.
"""

from __future__ import annotations

import time

# name -> (refine, edge fit, global mode)
VARIANTS: dict[str, tuple[str, bool, str]] = {
    "apriltag": ("apriltag", False, "per-frame"),
    "subpix": ("subpix", False, "per-frame"),
    "apriltag+edges": ("apriltag", True, "per-frame"),
    "apriltag+edges+static": ("apriltag", True, "static"),
    "subpix+edges+static": ("subpix", True, "static"),
}
BASELINE = "apriltag"


def _rendered(n_frames: int, seed: int):
    import numpy as np

    from lesscli.vision import render
    from lesscli.vision.camera import default_camera
    from lesscli.vision.track import Frame

    cam = default_camera()
    rng = np.random.default_rng(seed)
    traj = render.make_trajectory(rng, n_frames, step=max(1, 300 // n_frames))
    frames = []
    for i in range(n_frames):
        tags = [render.TagPlacement(0, traj["T_cam_global"]),
                render.TagPlacement(1, traj["T_cam_sensor_tag"][i])]
        frames.append(Frame(i, float(traj["time_s"][i]), str(i), render.render_frame(cam, tags, 31.0, rng)))
    return cam, traj, frames


def _run_variant(cam, traj, frames, refine: str, edge_fit: bool, mode: str) -> dict:
    import numpy as np

    from lesscli.geometry import rotations
    from lesscli.vision import se3
    from lesscli.vision.detect import TagDetector
    from lesscli.vision.track import TrackOptions, detect_all, solve_frames

    start = time.perf_counter()
    dets = detect_all(iter(frames), TagDetector(refine, camera=cam, edge_fit=edge_fit), cam)
    rows = list(solve_frames(cam, dets, TrackOptions(refine=refine, global_mode=mode)))
    seconds = (time.perf_counter() - start) / len(frames)
    ok = np.array([r["ok"] for r in rows])
    est = se3.pose_to_T(np.array([r["position_mm"] for r in rows])[ok],
                        np.array([r["rotvec_rad"] for r in rows])[ok])
    true = (se3.inv_T(traj["T_cam_global"]) @ traj["T_cam_sensor_tag"])[ok]
    pos = np.linalg.norm(est[:, :3, 3] - true[:, :3, 3], axis=1)
    ang = np.rad2deg(rotations.rotation_angle(np.swapaxes(true[:, :3, :3], 1, 2) @ est[:, :3, :3]))
    return {"frames_ok": int(ok.sum()), "median_position_mm": float(np.median(pos)),
            "p90_position_mm": float(np.percentile(pos, 90)), "median_angle_deg": float(np.median(ang)),
            "p90_angle_deg": float(np.percentile(ang, 90)), "seconds_per_frame": seconds}


def run_pose(n_frames: int, seed: int) -> list[dict]:
    """One row per variant on one rendered set of ``n_frames`` frames, with ratios against ``BASELINE``."""
    cam, traj, frames = _rendered(n_frames, seed)
    results = {name: _run_variant(cam, traj, frames, *spec) for name, spec in VARIANTS.items()}
    base = results[BASELINE]
    return [{"variant": name, "frames": n_frames, **res,
             "position_vs_baseline": res["median_position_mm"] / base["median_position_mm"],
             "angle_vs_baseline": res["median_angle_deg"] / base["median_angle_deg"]}
            for name, res in results.items()]
