"""Calibration to the robot frame: Kabsch, RANSAC, clock offset, degenerate input, accuracy figures."""

import numpy as np
import pytest

from lesscli.errors import DataError
from lesscli.geometry import rotations
from lesscli.vision.accuracy import pose_errors, sigma, summarize
from lesscli.vision.calibrate import Calibration, apply_to_pose6, calibrate, kabsch, ransac_kabsch
from lesscli.vision.streams import PoseStream, sync

TRUE_ROT = rotations.rotvec_to_matrix(np.array([0.3, -1.1, 0.6]))
TRUE_T = np.array([412.0, -87.0, 233.0])
TRUE_ORI = rotations.rotvec_to_matrix(np.array([0.05, 0.4, -0.2]))
OFFSET_S = 0.137


def _motion(t):
    """Hand-held-like motion in the tracked (global tag) frame: positions mm, rotations."""
    pos = np.stack([60 * np.sin(0.7 * t) + 20 * np.sin(2.3 * t), 45 * np.sin(1.1 * t + 1.0),
                    25 * np.sin(0.5 * t + 0.3) + 10 * np.cos(1.9 * t)], axis=1)
    rv = np.stack([0.3 * np.sin(0.9 * t), 0.25 * np.sin(0.6 * t + 2), 0.4 * np.sin(0.4 * t)], axis=1)
    return pos, rotations.rotvec_to_matrix(rv)


def _streams(rng, noise_mm=1.0, outliers=0.2, offset_s=OFFSET_S, duration_s=30.0):
    """Robot stream at 100 Hz (truth in the robot frame and clock) and a noisy tracked stream at 30 Hz."""
    t_rob = np.arange(0, duration_s, 0.01)
    pos, rot = _motion(t_rob)
    robot = PoseStream(t_rob, pos @ TRUE_ROT.T + TRUE_T, TRUE_ROT @ rot @ TRUE_ORI)
    t_est = np.arange(0.5, duration_s - 0.5, 1 / 30)        # tracked clock: robot time = t_est + offset
    pos_e, rot_e = _motion(t_est + offset_s)
    pos_e = pos_e + rng.normal(0, noise_mm, pos_e.shape)
    bad = rng.random(len(t_est)) < outliers
    pos_e[bad] += rng.uniform(-60, 60, (bad.sum(), 3))
    rot_e = rot_e @ rotations.rotvec_to_matrix(rng.normal(0, 0.005, (len(t_est), 3)))
    return PoseStream(t_est, pos_e, rot_e), robot


def test_kabsch_exact_and_never_reflects():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(20, 3)) * 50
    rot, t = kabsch(src, src @ TRUE_ROT.T + TRUE_T)
    assert np.allclose(rot, TRUE_ROT) and np.allclose(t, TRUE_T)
    mirrored = src * np.array([1, 1, -1])                    # only a reflection would fit exactly
    rot_m, _ = kabsch(src, mirrored)
    assert np.isclose(np.linalg.det(rot_m), 1.0)


def test_calibration_recovers_transform_from_noisy_streams():
    rng = np.random.default_rng(1)
    est, robot = _streams(rng)
    cal = calibrate(est, robot, np.random.default_rng(2))
    angle_deg = np.rad2deg(rotations.rotation_angle(TRUE_ROT.T @ cal.r_pos))
    print(f"offset {cal.time_offset_s:.4f} s, t error {np.linalg.norm(cal.t_pos - TRUE_T):.3f} mm, "
          f"R error {angle_deg:.4f} deg, inliers {cal.inlier_fraction:.2f}")
    assert abs(cal.time_offset_s - OFFSET_S) < 0.005
    assert np.linalg.norm(cal.t_pos - TRUE_T) <= 0.5
    assert angle_deg <= 0.2
    assert np.rad2deg(rotations.rotation_angle(TRUE_ORI.T @ cal.R_ori)) <= 0.2
    assert 0.7 < cal.inlier_fraction < 0.9
    # mapped back, the inlying tracked poses land on the robot's within the noise
    errors = pose_errors(est, robot, cal)
    assert np.median(np.linalg.norm(errors["position_mm"], axis=1)) < 2.5


def test_collinear_points_raise():
    rng = np.random.default_rng(3)
    s = rng.uniform(-50, 50, 200)
    line = np.stack([s, 2 * s, -s], axis=1)
    with pytest.raises(DataError, match="one line"):
        ransac_kabsch(line, line @ TRUE_ROT.T + TRUE_T, rng)


def test_fewer_than_three_points_raise():
    pts = np.array([[0.0, 0, 0], [1.0, 2, 3]])
    with pytest.raises(DataError, match="at least 3"):
        ransac_kabsch(pts, pts, np.random.default_rng(0))
    two = PoseStream(np.array([0.0, 0.1]), pts, np.stack([np.eye(3)] * 2))
    with pytest.raises(DataError, match="need at least"):
        calibrate(two, two, np.random.default_rng(0))


def test_no_time_overlap_raises():
    rng = np.random.default_rng(4)
    est, robot = _streams(rng, outliers=0.0)
    late = PoseStream(est.time_s + 100.0, est.position_mm, est.rotation)
    with pytest.raises(DataError, match="no time overlap"):
        calibrate(late, robot, rng)


def test_sync_interpolates_reference_at_shifted_times():
    ref = PoseStream(np.array([0.0, 1.0]), np.array([[0.0, 0, 0], [10.0, 0, 0]]),
                     rotations.rotvec_to_matrix(np.array([[0, 0, 0], [0, 0, 1.0]])))
    est = PoseStream(np.array([0.2, 0.6, 0.95]), np.zeros((3, 3)), np.stack([np.eye(3)] * 3))
    kept, matched = sync(est, ref, 0.1)
    assert np.allclose(kept.time_s, [0.2, 0.6])                  # 0.95 + 0.1 is past the reference
    assert np.allclose(matched.position_mm[:, 0], [3.0, 7.0])
    assert np.allclose(rotations.matrix_to_rotvec(matched.rotation)[:, 2], [0.3, 0.7])


def test_sigma_matches_the_paper_definition():
    errors = np.array([[1.0, 2.0, 2.0], [0.0, 0.0, 3.0]])
    assert np.isclose(sigma(errors), np.sqrt((1 + 4 + 4 + 9) / 6))
    row = summarize({"time_s": np.arange(2.0), "position_mm": errors, "angle_rad": errors * 0.01}, 3)
    assert row["n_poses"] == 2 and row["n_skipped"] == 1
    assert np.isclose(row["rms_z_mm"], np.sqrt((4 + 9) / 2)) and np.isclose(row["bias_x_mm"], 0.5)


def test_apply_to_scan_poses_uses_published_layout():
    cal = Calibration(TRUE_ROT, TRUE_T, TRUE_ORI, np.eye(3))     # published file: R_pre = I
    pose = np.array([[10.0, -5.0, 2.0, 0.1, -0.2, 0.3]])
    out = apply_to_pose6(pose, cal)
    assert np.allclose(out[0, :3], pose[0, :3] @ TRUE_ROT.T + TRUE_T)
    assert np.allclose(rotations.euler_to_matrix(out[0, 3:]),
                       rotations.euler_to_matrix(pose[0, 3:]) @ TRUE_ORI)
