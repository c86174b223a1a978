"""SE(3)/SO(3) algebra: hand-derived values and round trips against OpenCV's Rodrigues."""

import cv2
import numpy as np
import pytest

from lesscli.geometry import rotations
from lesscli.vision import se3


def _random_rotvecs(rng, n, max_angle=np.pi):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return axis * rng.uniform(0, max_angle, size=(n, 1))


def test_rotvec_matches_opencv_and_round_trips():
    rng = np.random.default_rng(0)
    rv = _random_rotvecs(rng, 200, max_angle=np.pi - 1e-3)
    rot = rotations.rotvec_to_matrix(rv)
    ref = np.array([cv2.Rodrigues(v)[0] for v in rv])
    assert np.abs(rot - ref).max() < 1e-12
    assert np.abs(rotations.matrix_to_rotvec(rot) - rv).max() < 1e-9


def test_hand_derived_rotations():
    quarter = rotations.rotvec_to_matrix(np.array([0.0, 0.0, np.pi / 2]))
    assert np.allclose(quarter @ [1.0, 0, 0], [0, 1.0, 0])
    half = rotations.matrix_to_rotvec(np.diag([1.0, -1.0, -1.0]))   # 180 degrees about x
    assert np.isclose(np.linalg.norm(half), np.pi) and np.allclose(np.abs(half), [np.pi, 0, 0])
    assert np.allclose(rotations.matrix_to_rotvec(np.eye(3)), 0.0)
    tiny = np.array([1e-10, -2e-10, 0.0])
    assert np.allclose(rotations.matrix_to_rotvec(rotations.rotvec_to_matrix(tiny)), tiny, atol=1e-16)


def test_quaternion_round_trip_and_sign():
    rng = np.random.default_rng(1)
    rot = rotations.rotvec_to_matrix(_random_rotvecs(rng, 100))
    q = rotations.matrix_to_quat(rot)
    assert np.all(q[:, 0] >= 0) and np.allclose(np.linalg.norm(q, axis=1), 1.0)
    assert np.abs(rotations.quat_to_matrix(q) - rot).max() < 1e-12


def test_slerp_halfway_is_half_angle_and_takes_short_way():
    q0 = rotations.matrix_to_quat(np.eye(3))[None]
    q1 = rotations.matrix_to_quat(rotations.rotvec_to_matrix(np.array([0.0, 0.0, 1.2])))[None]
    mid = rotations.quat_to_matrix(rotations.slerp(q0, q1, np.array([0.5])))[0]
    assert np.allclose(rotations.matrix_to_rotvec(mid), [0, 0, 0.6])
    # same rotation, other sign
    mid_neg = rotations.quat_to_matrix(rotations.slerp(q0, -q1, np.array([0.5])))[0]
    assert np.allclose(mid_neg, mid)


def test_interpolate_poses_linear_position_slerp_rotation():
    t = np.array([0.0, 1.0, 3.0])
    pos = np.array([[0.0, 0, 0], [10.0, 0, 0], [10.0, 20.0, 0]])
    rot = rotations.rotvec_to_matrix(np.array([[0, 0, 0], [0, 0, 0.4], [0, 0, 0.8]]))
    p, r = se3.interpolate_poses(t, pos, rot, np.array([0.25, 2.0]))
    assert np.allclose(p, [[2.5, 0, 0], [10.0, 10.0, 0]])
    assert np.allclose(rotations.matrix_to_rotvec(r), [[0, 0, 0.1], [0, 0, 0.6]])


def test_inverse_and_composition():
    rng = np.random.default_rng(2)
    T = se3.pose_to_T(rng.normal(size=(5, 3)) * 100, _random_rotvecs(rng, 5))
    assert np.allclose(se3.inv_T(T) @ T, np.eye(4), atol=1e-12)
    pos, rv = se3.T_to_pose(T)
    assert np.allclose(se3.pose_to_T(pos, rv), T)


def test_euler_convention_and_round_trip():
    rpy = np.array([0.1, -0.2, 0.3])
    expected = (rotations.rotvec_to_matrix(np.array([0, 0, 0.3]))
                @ rotations.rotvec_to_matrix(np.array([0, -0.2, 0]))
                @ rotations.rotvec_to_matrix(np.array([0.1, 0, 0])))
    assert np.allclose(rotations.euler_to_matrix(rpy), expected)
    assert np.allclose(rotations.matrix_to_euler(expected), rpy)


@pytest.mark.parametrize("flip", [False, True])
def test_project_to_so3_never_reflects(flip):
    rng = np.random.default_rng(3)
    m = rotations.rotvec_to_matrix(np.array([0.3, 0.2, -0.1])) + rng.normal(0, 0.01, (3, 3))
    if flip:
        m = m @ np.diag([1.0, 1.0, -1.0])
    r = rotations.project_to_so3(m)
    assert np.isclose(np.linalg.det(r), 1.0) and np.allclose(r.T @ r, np.eye(3))
