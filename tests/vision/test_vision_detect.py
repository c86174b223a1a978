"""AprilTag detection on rendered frames: corner order, marker frame, half-pixel offset, pose accuracy."""

import numpy as np
import pytest

from lesscli.geometry import rotations
from lesscli.vision import render, se3
from lesscli.vision.camera import Camera, default_camera
from lesscli.vision.detect import TagDetector, solve_tag_pose, tag_object_points
from lesscli.vision.track import Frame, TrackOptions, detect_all, solve_frames

TAG_MM = 31.0


def _true_corners(camera, T):
    return render.project(camera, tag_object_points(TAG_MM) @ T[:3, :3].T + T[:3, 3])


def _frame(camera, placements, seed=0, **effects):
    return render.render_frame(camera, placements, TAG_MM, np.random.default_rng(seed),
                               render.RenderEffects(**effects))


def test_corner_order_and_marker_frame_convention():
    """A tag facing the camera upright: corners TL, TR, BR, BL in the image; x right, y up, z to the
    camera."""
    cam = Camera(900.0, 900.0, 639.5, 359.5, 1280, 720)
    T = se3.make_T(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 400.0])
    found = TagDetector("apriltag", camera=cam).detect(_frame(cam, [render.TagPlacement(5, T)]))
    assert list(found) == [5]
    c = found[5]
    assert c[0, 0] < c[1, 0] and c[0, 1] < c[3, 1]          # 0 top-left: left of 1, above 3
    assert c[2, 0] > c[3, 0] and c[2, 1] > c[1, 1]          # 2 bottom-right
    assert np.abs(c - _true_corners(cam, T)).max() < 0.1
    pose = solve_tag_pose(cam, c, TAG_MM).T_cam_tag
    assert np.allclose(pose[:3, 0], [1, 0, 0], atol=0.01)    # x: image right
    assert np.allclose(pose[:3, 1], [0, -1, 0], atol=0.01)   # y: image up (camera y points down)
    assert np.allclose(pose[:3, 2], [0, 0, -1], atol=0.01)   # z: out of the tag, towards the camera
    assert np.allclose(pose[:3, 3], [0, 0, 400.0], atol=0.5)


def test_corner_order_follows_the_tag_when_it_turns():
    cam = default_camera()
    T = se3.make_T(render.facing_rotation(np.array([0.0, 0.0, np.pi / 2 + 0.2])), [20.0, -10.0, 450.0])
    found = TagDetector("apriltag", camera=cam).detect(_frame(cam, [render.TagPlacement(3, T)]))
    assert np.abs(found[3] - _true_corners(cam, T)).max() < 0.15


def test_apriltag_half_pixel_offset_is_corrected():
    cam = default_camera()
    rng = np.random.default_rng(4)
    traj = render.make_trajectory(rng, 6, step=15)
    raw, fixed = (TagDetector("apriltag", corner_offset_px=0.0, edge_fit=False),
                  TagDetector("apriltag", edge_fit=False))
    err_raw, err_fixed = [], []
    for i in range(6):
        T = traj["T_cam_sensor_tag"][i]
        image = _frame(cam, [render.TagPlacement(1, T)], seed=i)
        true = _true_corners(cam, T)
        err_raw.append(raw.detect(image)[1] - true)
        err_fixed.append(fixed.detect(image)[1] - true)
    bias_raw = np.mean(err_raw, axis=(0, 1))
    bias_fixed = np.mean(err_fixed, axis=(0, 1))
    assert np.all(np.abs(bias_raw) > 0.3)       # OpenCV's AprilTag corners sit about half a pixel off
    assert np.all(np.abs(bias_fixed) < 0.12)


def test_planar_ambiguity_picks_the_true_pose_from_exact_corners():
    cam = default_camera()
    T = se3.make_T(render.facing_rotation(np.array([0.45, -0.2, 0.1])), [60.0, 30.0, 600.0])
    pose = solve_tag_pose(cam, _true_corners(cam, T), TAG_MM)
    assert rotations.rotation_angle(T[:3, :3].T @ pose.T_cam_tag[:3, :3]) < 1e-6
    assert pose.alternative is not None
    assert rotations.rotation_angle(T[:3, :3].T @ pose.alternative[:3, :3]) > np.deg2rad(5)


@pytest.fixture(scope="module")
def rendered_set():
    """A fixed set: 1280x720, f = 900 px, tags 0.35-0.7 m away, tilts within 35 degrees."""
    cam = default_camera()
    rng = np.random.default_rng(7)
    traj = render.make_trajectory(rng, 10, step=11)
    frames = []
    for i in range(10):
        tags = [render.TagPlacement(0, traj["T_cam_global"]),
                render.TagPlacement(1, traj["T_cam_sensor_tag"][i])]
        frames.append(Frame(i, float(traj["time_s"][i]), f"f{i}",
                            render.render_frame(cam, tags, TAG_MM, rng)))
    return cam, traj, frames


def test_rendered_set_spans_the_required_range(rendered_set):
    _, traj, _ = rendered_set
    depth = traj["T_cam_sensor_tag"][:, 2, 3]
    tilt = np.rad2deg(rotations.rotation_angle(np.diag([1.0, -1.0, -1.0])
                                               @ traj["T_cam_sensor_tag"][:, :3, :3]))
    assert depth.min() >= 350 and depth.max() <= 700 and depth.max() - depth.min() > 150
    assert tilt.max() <= 35.0 and tilt.max() > 20.0


def _pose_errors(cam, traj, frames, refine, mode="static"):
    dets = detect_all(iter(frames), TagDetector(refine, camera=cam), cam)
    rows = list(solve_frames(cam, dets, TrackOptions(refine=refine, global_mode=mode)))
    assert all(r["ok"] for r in rows)
    est = se3.pose_to_T(np.array([r["position_mm"] for r in rows]), np.array([r["rotvec_rad"] for r in rows]))
    true = se3.inv_T(traj["T_cam_global"]) @ traj["T_cam_sensor_tag"]
    pos = np.linalg.norm(est[:, :3, 3] - true[:, :3, 3], axis=1)
    ang = np.rad2deg(rotations.rotation_angle(np.swapaxes(true[:, :3, :3], 1, 2) @ est[:, :3, :3]))
    return pos, ang, rows


def test_sensor_pose_accuracy_with_apriltag_refinement(rendered_set):
    cam, traj, frames = rendered_set
    pos, ang, rows = _pose_errors(cam, traj, frames, "apriltag")
    print(f"median {np.median(pos):.3f} mm {np.median(ang):.3f} deg; max {pos.max():.3f} mm {ang.max():.3f} "
          "deg")
    assert np.median(pos) <= 0.5 and np.median(ang) <= 0.5
    assert all(r["reprojection_px"] < 0.2 for r in rows)


def test_frames_without_tags_are_not_guessed(rendered_set):
    cam, traj, frames = rendered_set
    blank = Frame(99, 9.9, "blank", np.full((cam.height, cam.width), 120, np.uint8))
    only_global = Frame(100, 10.0, "global-only", _frame(cam, [render.TagPlacement(0, traj["T_cam_global"])]))
    dets = detect_all(iter([frames[0], blank, only_global]), TagDetector("apriltag", camera=cam), cam)
    rows = list(solve_frames(cam, dets, TrackOptions()))
    assert [r["ok"] for r in rows] == [True, False, False]
    assert rows[1]["tags_seen"] == [] and np.isnan(rows[1]["position_mm"]).all()
    assert rows[2]["tags_seen"] == [0] and "sensor" in rows[2]["note"]
