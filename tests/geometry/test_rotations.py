"""Rotations: one table cross-checked against scipy.spatial.transform, then hand-derived values."""

import math

import numpy as np
import pytest
from published_fixture import rot_x, rot_z
from scipy.spatial.transform import Rotation, Slerp

from lesscli.geometry import rotations as rot

HALF_TURN_NEAR = np.pi - 1e-6   # angles beyond this have two rotation vectors (v and -v) for one rotation


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _wxyz(q_xyzw: np.ndarray) -> np.ndarray:
    return np.roll(q_xyzw, 1, axis=-1)


def _xyzw(q_wxyz: np.ndarray) -> np.ndarray:
    return np.roll(q_wxyz, -1, axis=-1)


_rng = np.random.default_rng(7)
ROTVECS = np.concatenate([
    [[0.0, 0.0, 0.0]],                                   # identity
    [[1e-10, -2e-10, 5e-11]],                            # below SMALL_ANGLE_RAD: the series branch
    [[3e-8, 0.0, 0.0]],                                  # just above it
    [[0.0, 0.0, np.pi / 2]],
    np.pi * np.eye(3),                                   # half turns about x, y, z
    [np.pi * _unit([1.0, -2.0, 0.5])],                   # a half turn about an oblique axis
    [(np.pi - 1e-7) * _unit([0.3, 0.4, -0.5])],          # nearly a half turn
    _unit(_rng.normal(size=(20, 3))) * _rng.uniform(0, np.pi, (20, 1)),
])
MATRICES = Rotation.from_rotvec(ROTVECS).as_matrix()
QUATS = _wxyz(Rotation.from_rotvec(ROTVECS).as_quat())
OTHER_QUATS = np.roll(QUATS, 3, axis=0)
ANGLES = np.array([0.0, 1e-12, 0.3, -1.2, np.pi / 2, np.pi, -np.pi, 5.0])
# pitch stays off +-pi/2: at gimbal lock roll and yaw are not separable (the convention reads yaw = 0),
# and near it both readings lose digits as eps / cos(pitch)
RPY = np.concatenate([
    [[0.0, 0.0, 0.0], [np.pi, 0.0, 0.0], [0.0, 0.0, np.pi], [0.1, -0.2, 0.3], [-3.0, 1.5, 2.9],
     [0.2, np.pi / 2 - 1e-3, -0.4]],
    _rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi], (20, 3)),
])


def _slerp_pairs() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    q_a = QUATS[-1]
    tiny = [_wxyz(Rotation.from_rotvec([0.0, angle, 0.0]).as_quat()) for angle in (1e-7, 1e-9, 1e-13)]
    pairs = [
        (np.array([1.0, 0, 0, 0]), QUATS[3], 0.25),      # identity -> quarter turn about z
        (np.array([1.0, 0, 0, 0]), QUATS[3], 1.0),
        (QUATS[5], QUATS[5], 0.4),                        # equal keys
        (q_a, -q_a, 0.5),                                 # antipodal: the same rotation, other sign
        *[(q_a, rot.quat_multiply(q_a, t), 0.3) for t in tiny],   # nearly equal keys
        (np.array([1.0, 0, 0, 0]), QUATS[4], 0.5),       # half a turn apart (about x)
        (np.array([1.0, 0, 0, 0]), _wxyz(Rotation.from_rotvec([np.deg2rad(170), 0, 0]).as_quat()), 0.5),
        *[(QUATS[i], OTHER_QUATS[i], f) for i, f in zip(range(10, 20), np.linspace(0, 1, 10))],
    ]
    q0, q1, frac = (np.array(x) for x in zip(*pairs))
    return q0, q1, frac


SLERP_Q0, SLERP_Q1, SLERP_FRAC = _slerp_pairs()
KEY_TIMES = np.array([0.0, 0.5, 0.7, 2.0, 2.1])
KEY_MATRICES = MATRICES[[3, 10, 11, 12, 13]]
QUERY_TIMES = np.array([0.0, 0.1, 0.5, 0.69, 1.3, 2.0, 2.05, 2.1])


def _scipy_slerp() -> np.ndarray:
    out = [Slerp([0.0, 1.0], Rotation.from_quat(_xyzw(np.stack([a, b]))))([f]).as_quat()[0]
           for a, b, f in zip(SLERP_Q0, SLERP_Q1, SLERP_FRAC)]
    return _wxyz(np.array(out))


# (name, ours, scipy's, how to compare)
CASES = [
    *[(f"axis_rotation {a}", lambda a=a: rot.axis_rotation(a, ANGLES),
       lambda a=a: Rotation.from_euler(a, ANGLES[:, None]).as_matrix(), "array") for a in "xyz"],
    ("rotvec_to_matrix", lambda: rot.rotvec_to_matrix(ROTVECS),
     lambda: Rotation.from_rotvec(ROTVECS).as_matrix(), "array"),
    ("matrix_to_rotvec", lambda: rot.matrix_to_rotvec(MATRICES),
     lambda: Rotation.from_matrix(MATRICES).as_rotvec(), "rotvec"),
    ("rotvec_to_quat", lambda: rot.rotvec_to_quat(ROTVECS),
     lambda: _wxyz(Rotation.from_rotvec(ROTVECS).as_quat()), "unit quat"),
    ("quat_to_rotvec", lambda: rot.quat_to_rotvec(QUATS),
     lambda: Rotation.from_quat(_xyzw(QUATS)).as_rotvec(), "rotvec"),
    ("quat_to_matrix (not unit)", lambda: rot.quat_to_matrix(2.5 * QUATS),
     lambda: Rotation.from_quat(_xyzw(QUATS)).as_matrix(), "array"),
    ("matrix_to_quat", lambda: rot.matrix_to_quat(MATRICES),
     lambda: _wxyz(Rotation.from_matrix(MATRICES).as_quat()), "unit quat"),
    ("quat_normalise", lambda: rot.quat_normalise(-3.0 * QUATS), lambda: QUATS, "unit quat"),
    ("quat_multiply", lambda: rot.quat_multiply(QUATS, OTHER_QUATS),
     lambda: _wxyz((Rotation.from_quat(_xyzw(QUATS)) * Rotation.from_quat(_xyzw(OTHER_QUATS))).as_quat()),
     "quat"),
    ("rotation_angle", lambda: rot.rotation_angle(MATRICES),
     lambda: Rotation.from_matrix(MATRICES).magnitude(), "array"),
    ("euler_to_matrix", lambda: rot.euler_to_matrix(RPY), lambda: Rotation.from_euler("xyz", RPY).as_matrix(),
     "array"),
    ("matrix_to_euler", lambda: rot.matrix_to_euler(Rotation.from_euler("xyz", RPY).as_matrix()),
     lambda: Rotation.from_euler("xyz", RPY).as_euler("xyz"), "angles"),
    ("slerp", lambda: rot.slerp(SLERP_Q0, SLERP_Q1, SLERP_FRAC), _scipy_slerp, "unit quat"),
    ("slerp_at", lambda: rot.slerp_at(KEY_TIMES, KEY_MATRICES, QUERY_TIMES),
     lambda: Slerp(KEY_TIMES, Rotation.from_matrix(KEY_MATRICES))(QUERY_TIMES).as_matrix(), "array"),
]


@pytest.mark.parametrize("name, ours, theirs, kind", CASES, ids=[c[0] for c in CASES])
def test_matches_scipy(name, ours, theirs, kind):
    got, want = ours(), theirs()
    assert got.shape == want.shape
    if kind == "rotvec":          # near a half turn v and -v are the same rotation
        angle = np.linalg.norm(want, axis=-1, keepdims=True)
        flip = (angle > HALF_TURN_NEAR) & (np.sum(got * want, axis=-1, keepdims=True) < 0)
        want = np.where(flip, -want, want)
        assert np.linalg.norm(got, axis=-1).max() <= np.pi + 1e-12
    elif kind in ("quat", "unit quat"):   # q and -q are the same rotation
        want = np.where(np.sum(got * want, axis=-1, keepdims=True) < 0, -want, want)
        if kind == "unit quat":
            np.testing.assert_allclose(np.linalg.norm(got, axis=-1), 1.0, atol=1e-12)
            assert got[..., 0].min() >= 0.0
    elif kind == "angles":        # the same angle up to whole turns
        want = got + np.angle(np.exp(1j * (want - got)))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 if kind == "rotvec" else 1e-12)


def test_axis_rotation_rejects_an_unknown_axis():
    with pytest.raises(ValueError, match="axis must be one of x, y, z, got 'w'"):
        rot.axis_rotation("w", 0.1)


def test_slerp_at_midpoint_of_quarter_turn_is_eighth_turn():
    keys = np.stack([np.eye(3), rot_z(np.pi / 2)])
    out = rot.slerp_at(np.array([0.0, 1.0]), keys, np.array([0.5, 0.25, 1.0]))
    np.testing.assert_allclose(out[0], rot_z(np.pi / 4), atol=1e-12)
    np.testing.assert_allclose(out[1], rot_z(np.pi / 8), atol=1e-12)
    np.testing.assert_allclose(out[2], rot_z(np.pi / 2), atol=1e-12)


def test_slerp_at_takes_the_short_way_and_handles_large_angles():
    out = rot.slerp_at(np.array([0.0, 2.0]), np.stack([rot_z(-0.1), rot_z(0.1)]), np.array([1.0]))
    np.testing.assert_allclose(out[0], np.eye(3), atol=1e-12)
    out = rot.slerp_at(np.array([0.0, 1.0]), np.stack([np.eye(3), rot_x(np.deg2rad(170))]), np.array([0.5]))
    np.testing.assert_allclose(out[0], rot_x(np.deg2rad(85)), atol=1e-12)


def test_quaternion_round_trip_near_half_turns():
    for r in (rot_x(np.pi), rot_z(np.pi) @ rot_x(0.3), rot_z(3.0) @ rot_x(-3.1), np.eye(3)):
        np.testing.assert_allclose(rot.quat_to_matrix(rot.matrix_to_quat(r[None]))[0], r, atol=1e-12)


def test_euler_conventions():
    # roll = atan2(R21, R22), pitch = atan2(-R20, hypot(R21, R22)), yaw = atan2(R10, R00)
    np.testing.assert_allclose(rot.matrix_to_euler(rot_x(np.pi / 2)[None]), [[np.pi / 2, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(rot.matrix_to_euler(rot_z(-0.7)[None]), [[0, 0, -0.7]], atol=1e-12)
    c, s = np.cos(0.4), np.sin(0.4)
    rot_y = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])  # R20 = -sin(pitch)
    np.testing.assert_allclose(rot.matrix_to_euler(rot_y[None]), [[0, 0.4, 0]], atol=1e-12)
    composed = rot_z(0.3) @ rot_y @ rot_x(-0.2)  # R = Rz(yaw) Ry(pitch) Rx(roll)
    np.testing.assert_allclose(rot.matrix_to_euler(composed[None]), [[-0.2, 0.4, 0.3]], atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, math.pi / 4, -3 * math.pi / 4, 2.0])
def test_turn_xy_is_the_z_rotation_and_keeps_other_columns(angle):
    rng = np.random.default_rng(3)
    points = rng.normal(0, 10, (7, 4))
    want = Rotation.from_euler("z", angle).apply(np.column_stack([points[:, :2], np.zeros(7)]))[:, :2]
    turned = rot.turn_xy(points, angle)
    np.testing.assert_allclose(turned[:, :2], want, atol=1e-12)
    np.testing.assert_array_equal(turned[:, 2:], points[:, 2:])
    assert turned is not points and np.array_equal(rot.turn_xy(points[:, :2], 0.0), points[:, :2])
