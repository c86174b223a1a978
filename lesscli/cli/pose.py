"""``less pose``: hand-held sensor pose from two AprilTags, calibration to the robot, accuracy.

cv2 and the vision modules are imported inside the command bodies only.
"""

from __future__ import annotations

import math

import click

from lesscli.cli.common import Group, checked_output, format_option, output_option, progress, seed_option

MAX_FRAME_WARNINGS = 5      # frames without a pose named on stderr before a count takes over


def _positive_rate(value: float | None) -> float | None:
    """``--fps``: a finite rate above 0 (nan and inf are refused, as 0 and negative rates are)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise click.BadParameter(f"{value!r}: a frame rate is a finite number of frames per second above 0",
                                 param_hint="'--fps'")
    return value


@click.group("pose", cls=Group)
def cli() -> None:
    """Track the sensor with AprilTags, render test frames, calibrate to the robot, measure accuracy."""


@cli.command("track")
@click.argument("frames", type=click.Path(), metavar="FRAMES")
@click.option("--camera", "camera_path", type=click.Path(), required=True,
              help="cam.json: fx, fy, cx, cy, width, height, dist.")
@output_option(help="Pose rows as JSON lines ('-' for stdout).")
@click.option("--sensor-tag", type=int, default=1, show_default=True,
              help="Id of the tag on the sensor handle.")
@click.option("--global-tag", type=int, default=0, show_default=True, help="Id of the fixed reference tag.")
@click.option("--tag-size-mm", type=float, default=31.0, show_default=True, help="Side of the black square.")
@click.option("--tag-to-sensor", "tag_to_sensor", type=click.Path(), default=None,
              help="T.json: 4x4 T_Stag<-S in mm (default identity).")
@click.option("--refine", type=click.Choice(["apriltag", "subpix", "none"]), default="apriltag",
              show_default=True, help="The detector's corner refinement.")
@click.option("--edge-fit/--no-edge-fit", default=True, show_default=True,
              help="Refine corners by fitting lines to each tag's outer edges.")
@click.option("--global-mode", type=click.Choice(["static", "per-frame"]), default="static",
              show_default=True,
              help="static: one PnP over the global tag's corners from all frames (fixed camera); "
                   "per-frame: solve it in every frame.")
@click.option("--fps", type=float, default=None, callback=lambda ctx, param, v: _positive_rate(v),
              help="Frame rate when there is no timestamps.txt (or to override).")
def track_cmd(frames: str, camera_path: str, output: str, sensor_tag: int, global_tag: int,
              tag_size_mm: float, tag_to_sensor: str | None, refine: str, edge_fit: bool, global_mode: str,
              fps: float | None) -> None:
    """Sensor pose in the global tag's frame for every frame of FRAMES.

    FRAMES is a folder of images (sorted by name, times from timestamps.txt or --fps) or a video file.
    Each output row: frame, t, position_mm, rotvec_rad, tags_seen, reprojection_px, ok; a frame missing a
    tag (or unreadable) gives "ok": false and null pose.

    Example: less pose track frames/ --camera frames/camera.json -o poses.jsonl
    """
    import numpy as np

    from lesscli.io.atomic import atomic_path
    from lesscli.io.records import emit_records
    from lesscli.vision.camera import load_camera
    from lesscli.vision.track import TrackOptions, load_tag_to_sensor, track

    camera = load_camera(camera_path)
    opts = TrackOptions(sensor_tag, global_tag, tag_size_mm, refine, global_mode,
                        load_tag_to_sensor(tag_to_sensor) if tag_to_sensor else np.eye(4))
    rows = track(frames, camera, opts, fps, edge_fit, lambda it: progress(it, desc="detect"))
    failed = [r for r in rows if not r["ok"]]
    for row in failed[:MAX_FRAME_WARNINGS]:
        click.echo(f"less: frame {row['frame']}: {row.get('note', 'no pose')}", err=True)
    if len(failed) > MAX_FRAME_WARNINGS:
        click.echo(f"less: ... and {len(failed) - MAX_FRAME_WARNINGS} more frames without a pose", err=True)
    if output == "-":
        emit_records(rows, "jsonl")
        return
    with atomic_path(output, ".jsonl") as tmp, open(tmp, "w", encoding="utf-8") as fh:
        emit_records(rows, "jsonl", stream=fh)
    n_ok = sum(r["ok"] for r in rows)
    click.echo(f"less: {n_ok}/{len(rows)} frames with a pose -> {output}", err=True)


@cli.command("render")
@click.option("--camera", "camera_path", type=click.Path(), default=None,
              help="cam.json (default: 1280x720, f = 900 px).")
@click.option("--trajectory", "trajectory", type=click.Path(), default=None,
              help="traj.npz: time_s, T_cam_global, T_cam_sensor_tag (mm); default: a generated hand-held "
                   "motion.")
@output_option(help="Output folder for the frames, timestamps.txt, camera.json and truth.npz.", folder=True)
@click.option("--frames", "n_frames", type=int, default=30, show_default=True,
              help="Frames of a generated motion.")
@click.option("--step", type=int, default=1, show_default=True,
              help="Generated motion: every step-th 30 fps frame.")
@click.option("--sensor-tag", type=int, default=1, show_default=True,
              help="Id of the tag drawn on the sensor handle.")
@click.option("--global-tag", type=int, default=0, show_default=True,
              help="Id of the fixed reference tag drawn.")
@click.option("--tag-size-mm", type=float, default=31.0, show_default=True, help="Side of the black square.")
@click.option("--blur-px", type=float, default=0.7, show_default=True, help="Gaussian blur sigma, px.")
@click.option("--noise", "noise_gray", type=float, default=2.0, show_default=True,
              help="Noise sigma, grey levels.")
@seed_option()
def render_cmd(camera_path: str | None, trajectory: str | None, output: str, n_frames: int, step: int,
               sensor_tag: int, global_tag: int, tag_size_mm: float, blur_px: float, noise_gray: float,
               seed: int) -> None:
    """Render synthetic frames of the sensor and global tags at known poses (truth saved beside them).

    Example: less pose render --frames 30 -o frames/
    """
    import numpy as np

    from lesscli.errors import DataError
    from lesscli.io.atomic import atomic_dir
    from lesscli.vision import render
    from lesscli.vision.camera import default_camera, load_camera

    camera = load_camera(camera_path) if camera_path else default_camera()
    rng = np.random.default_rng(seed)
    if trajectory:
        traj = render.load_trajectory(trajectory)
    else:
        if n_frames < 1 or step < 1:
            raise DataError("--frames and --step must be at least 1")
        traj = render.make_trajectory(rng, n_frames, step=step)
    effects = render.RenderEffects(blur_px=blur_px, noise_gray=noise_gray)
    with atomic_dir(output) as tmp:
        n = render.render_sequence(camera, traj, tmp, rng, tag_size_mm, sensor_tag, global_tag, effects,
                                   progress=lambda it: progress(it, desc="render"))
    click.echo(f"less: {n} frames -> {output}", err=True)


@cli.command("calibrate")
@click.argument("estimated", type=click.Path(), metavar="ESTIMATED")
@click.argument("robot", type=click.Path(), metavar="ROBOT")
@output_option(help="Calibration .npz (r_pos, t_pos, R_ori, R_pre, time_offset_s).")
@click.option("--threshold-mm", type=float, default=3.0, show_default=True, help="RANSAC inlier distance.")
@click.option("--max-offset-s", type=float, default=0.5, show_default=True,
              help="Search the clock offset within +-this (0: clocks agree).")
@click.option("--time-offset-s", type=float, default=None, help="A known clock offset (skips the search).")
@click.option("--iterations", type=int, default=300, show_default=True, help="RANSAC iterations.")
@format_option()
@seed_option()
def calibrate_cmd(estimated: str, robot: str, output: str, threshold_mm: float, max_offset_s: float,
                  time_offset_s: float | None, iterations: int, fmt: str | None, seed: int) -> None:
    """Fit tracked poses (ESTIMATED, .jsonl or .npz) to robot poses (ROBOT, .npz): clock offset, then
    Kabsch (no reflection, no scale) inside RANSAC, then the orientation offset. Prints one summary row.

    Example: less pose calibrate poses.jsonl robot.npz -o est_to_robot_calibration.npz
    """
    import numpy as np

    from lesscli.geometry import rotations
    from lesscli.io.records import emit_records
    from lesscli.vision.calibrate import calibrate, save_calibration
    from lesscli.vision.streams import load_stream

    cal = calibrate(load_stream(estimated), load_stream(robot), np.random.default_rng(seed), threshold_mm,
                    max_offset_s, time_offset_s, iterations)
    save_calibration(output, cal, seed=seed)
    emit_records([{"output": output, "time_offset_s": cal.time_offset_s,
                   "inlier_fraction": cal.inlier_fraction, "rmse_mm": cal.rmse_mm, "t_pos_mm": cal.t_pos,
                   "r_pos_rotvec_rad": rotations.matrix_to_rotvec(cal.r_pos),
                   "R_ori_rotvec_rad": rotations.matrix_to_rotvec(cal.R_ori)}], fmt)


@cli.command("accuracy")
@click.argument("estimated", type=click.Path(), metavar="ESTIMATED")
@click.argument("reference", type=click.Path(), metavar="ROBOT")
@click.option("--calibration", type=click.Path(), default=None,
              help="Calibration .npz applied to ESTIMATED first.")
@click.option("--plot", "plot_path", type=click.Path(), default=None, callback=checked_output(),
              help="PNG of the per-axis errors over time.")
@format_option()
def accuracy_cmd(estimated: str, reference: str, calibration: str | None, plot_path: str | None,
                 fmt: str | None) -> None:
    """sigma_positional and sigma_angular (paper appendix), per-axis RMS and bias, medians and maxima.

    Example: less pose accuracy poses.jsonl frames/truth.npz --plot error.png --format table
    """
    from lesscli.io.records import emit_records
    from lesscli.vision.accuracy import plot_errors, pose_errors, summarize
    from lesscli.vision.calibrate import load_calibration
    from lesscli.vision.streams import load_stream

    est = load_stream(estimated)
    errors = pose_errors(est, load_stream(reference), load_calibration(calibration) if calibration else None)
    if plot_path:
        plot_errors(errors, plot_path, title=estimated)
    emit_records([summarize(errors, len(est))], fmt)


@cli.command("apply")
@click.argument("calibration", type=click.Path(), metavar="CALIB")
@click.argument("scans", type=click.Path(), metavar="SCANS")
@output_option(help="Output scan set .npz ('-' for stdout).")
def apply_cmd(calibration: str, scans: str, output: str) -> None:
    """Apply a calibration (p <- p r_pos^T + t_pos, R <- R_pre R R_ori) to a scan set's poses.

    Example: less pose apply est_to_robot_calibration.npz scans.npz -o scans_robot.npz
    """
    from dataclasses import replace

    import numpy as np

    from lesscli.io.scans import append_history, load_scans, save_scans
    from lesscli.vision.calibrate import apply_to_pose6, load_calibration

    cal = load_calibration(calibration)
    data = load_scans(scans)
    pose = apply_to_pose6(data.pose, cal).astype(np.float32)
    save_scans(output, replace(data, pose=pose, meta=append_history(data.meta, calibration=calibration)))
