"""Tracking logic on exact corners (no rendering): frame chain, tag-to-sensor, static global tag, inputs."""

import json

import cv2
import numpy as np
import pytest

from lesscli.errors import DataError
from lesscli.geometry import rotations
from lesscli.vision import render, se3
from lesscli.vision.camera import default_camera, load_camera
from lesscli.vision.detect import tag_object_points
from lesscli.vision.track import (
    Frame,
    TrackOptions,
    iter_frames,
    load_tag_to_sensor,
    read_timestamps,
    solve_frames,
)

TAG_MM = 31.0
CAM = default_camera()


def _corners(T):
    return render.project(CAM, tag_object_points(TAG_MM) @ T[:3, :3].T + T[:3, 3])


def _detections(T_global, T_sensors):
    image = np.zeros((1, 1), np.uint8)
    return [{"frame": Frame(i, i / 30, str(i), image),
             "corners": {0: _corners(T_global[i] if T_global.ndim == 3 else T_global), 1: _corners(T)}}
            for i, T in enumerate(T_sensors)]


def test_chain_and_tag_to_sensor_offset():
    traj = render.make_trajectory(np.random.default_rng(0), 5, step=20)
    offset = se3.make_T(rotations.rotvec_to_matrix(np.array([0.0, 0.3, 0.1])), [5.0, -12.0, 30.0])
    opts = TrackOptions(T_stag_sensor=offset)
    rows = list(solve_frames(CAM, _detections(traj["T_cam_global"], traj["T_cam_sensor_tag"]), opts))
    true = se3.inv_T(traj["T_cam_global"]) @ traj["T_cam_sensor_tag"] @ offset
    est = se3.pose_to_T(np.array([r["position_mm"] for r in rows]), np.array([r["rotvec_rad"] for r in rows]))
    assert np.abs(est[:, :3, 3] - true[:, :3, 3]).max() < 1e-3
    assert rotations.rotation_angle(np.swapaxes(true[:, :3, :3], 1, 2) @ est[:, :3, :3]).max() < 1e-6


def test_static_global_tag_falls_back_per_frame_when_it_moves():
    traj = render.make_trajectory(np.random.default_rng(1), 6, step=20)
    glob = np.repeat(traj["T_cam_global"][None], 6, axis=0)
    # camera bumped in the last frame
    glob[5] = se3.make_T(glob[5][:3, :3], glob[5][:3, 3] + [20.0, 0, 0])
    rows = list(solve_frames(CAM, _detections(glob, traj["T_cam_sensor_tag"]), TrackOptions()))
    true = se3.inv_T(glob) @ traj["T_cam_sensor_tag"]
    pos = np.array([r["position_mm"] for r in rows])
    assert np.abs(pos - true[:, :3, 3]).max() < 1e-3
    assert "moved" in rows[5]["note"] and "note" not in rows[0]


def test_timestamps_plain_and_named(tmp_path):
    plain = tmp_path / "t.txt"
    plain.write_text("0.0\n0.033\n# comment\n0.07\n")
    assert np.allclose(read_timestamps(str(plain), ["a", "b", "c"]), [0, 0.033, 0.07])
    named = tmp_path / "n.txt"
    named.write_text("b.png 2.0\na.png 1.0\n")
    assert np.allclose(read_timestamps(str(named), ["a.png", "b.png"]), [1.0, 2.0])
    with pytest.raises(DataError, match="3 times for 2 images"):
        read_timestamps(str(plain), ["a", "b"])
    with pytest.raises(DataError, match="no time for image 'c.png'"):
        read_timestamps(str(named), ["a.png", "b.png", "c.png"])


def test_video_input_and_missing_rate(tmp_path):
    path = str(tmp_path / "clip.avi")
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (64, 48))
    if not writer.isOpened():
        pytest.fail("OpenCV cannot write an MJPG test video")
    for k in range(3):
        writer.write(np.full((48, 64, 3), 40 * k, np.uint8))
    writer.release()
    frames = list(iter_frames(path))
    assert [f.index for f in frames] == [0, 1, 2] and np.allclose([f.time_s for f in frames],
                                                                  [0, 1 / 15, 2 / 15])
    assert frames[0].image.shape == (48, 64)
    with pytest.raises(DataError, match="no such folder or video"):
        iter_frames(str(tmp_path / "missing.avi"))


def test_folder_without_times_needs_fps(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(DataError, match="--fps"):
        list(iter_frames(str(tmp_path)))
    assert [f.time_s for f in iter_frames(str(tmp_path), fps=10.0)] == [0.0]


def test_tag_to_sensor_and_camera_files_are_checked(tmp_path):
    good = tmp_path / "T.json"
    good.write_text(json.dumps(np.eye(4).tolist()))
    assert np.allclose(load_tag_to_sensor(str(good)), np.eye(4))
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps((2 * np.eye(4)).tolist()))
    with pytest.raises(DataError, match="not a rigid transform"):
        load_tag_to_sensor(str(bad))
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"fx": -1, "fy": 900, "cx": 1, "cy": 1, "width": 10, "height": 10}))
    with pytest.raises(DataError, match="positive"):
        load_camera(str(cam))
