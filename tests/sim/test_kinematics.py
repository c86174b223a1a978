"""Pad kinematics: Euler convention, taxel centres, corners, tilt and the vertical projection."""

import math

import numpy as np
import pytest

from lesscli.errors import SimulationError
from lesscli.geometry.rotations import euler_to_matrix
from lesscli.io.sensor import xela_uscu
from lesscli.sim import kinematics as kin


def test_rotation_matches_recorded_euler_convention():
    rng = np.random.default_rng(0)
    rpy = rng.uniform([-1, -1.2, -3], [1, 1.2, 3], size=(50, 3))
    r = euler_to_matrix(rpy)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", r, r), np.broadcast_to(np.eye(3), r.shape),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    # REFERENCE.md: roll = atan2(R21, R22), pitch = atan2(-R20, sqrt(R21^2 + R22^2)), yaw = atan2(R10, R00)
    back = np.stack([np.arctan2(r[:, 2, 1], r[:, 2, 2]),
                     np.arctan2(-r[:, 2, 0], np.hypot(r[:, 2, 1], r[:, 2, 2])),
                     np.arctan2(r[:, 1, 0], r[:, 0, 0])], 1)
    np.testing.assert_allclose(back, rpy, atol=1e-12)


def test_taxel_centres_follow_yaw_and_translation():
    sensor = xela_uscu()
    xy = np.asarray(sensor["taxel_xy_mm"])
    pose = np.array([[3.0, -2.0, -1.5, 0.0, 0.0, math.pi / 2]])
    c = kin.taxel_centres_mm(pose, sensor)[0]
    np.testing.assert_allclose(c[:, 0], 3.0 - xy[:, 1], atol=1e-12)
    np.testing.assert_allclose(c[:, 1], -2.0 + xy[:, 0], atol=1e-12)
    np.testing.assert_allclose(c[:, 2], -1.5)
    np.testing.assert_allclose(kin.pad_normals(pose)[0], [0, 0, 1], atol=1e-12)


def test_corners_and_tilt():
    pose = np.array([[0, 0, 0, 0.0, math.radians(20), 0.0], [0, 0, 0, math.radians(40), 0, 0.3]])
    corners = kin.pad_corners_mm(pose, (10.0, 6.0))
    assert corners.shape == (2, 4, 3)
    np.testing.assert_allclose(corners[0, 1, 2] - corners[0, 0, 2], -10.0 * math.sin(math.radians(20)),
                               atol=1e-12)
    np.testing.assert_allclose(kin.tilt_rad(pose), [math.radians(20), math.radians(40)], atol=1e-12)
    assert kin.outside_validity(pose).tolist() == [False, True]


def test_projection_inverts_pad_to_world():
    rng = np.random.default_rng(1)
    pose = np.concatenate([rng.uniform(-5, 5, (7, 3)), rng.uniform(-0.4, 0.4, (7, 3))], 1)
    local = rng.uniform(-10, 10, (20, 2))
    world = kin.pad_to_world(pose, local)                  # (7, 20, 3)
    proj = kin.project_surface(pose, world[..., :2])
    np.testing.assert_allclose(proj.local_xy_mm, np.broadcast_to(local, (7, 20, 2)), atol=1e-9)
    np.testing.assert_allclose(proj.penetration_mm, -world[..., 2], atol=1e-9)


@pytest.mark.parametrize("bad, word",
                         [([0, 0, 0, math.pi / 2, 0, 0], "90"), ([0, np.nan, 0, 0, 0, 0], "finite"),
                                       ([0, 0, 0, math.pi, 0, 0], "180")])
def test_bad_poses_name_the_sample(bad, word):
    pose = np.array([[0, 0, 0, 0, 0, 0], bad], dtype=float)
    with pytest.raises(SimulationError, match="sample 1") as err:
        kin.check_poses(pose)
    assert word in str(err.value)
