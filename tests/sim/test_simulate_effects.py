"""Effect models against hand-derived values."""

import math

import numpy as np
import pytest

from lesscli.io.sensor import xela_uscu
from lesscli.phantom.catalogue import CATALOGUES
from lesscli.sim.effects import noise, pose_tracking, sensor, shear, tilt, variability, viscoelastic
from lesscli.sim.pipeline import stream
from lesscli.sim.state import SimState, rotate_pose, taxel_world_xy

SENSOR = xela_uscu()
TXY = np.asarray(SENSOR["taxel_xy_mm"])


def state_with(force, pose=None, lengths=None):
    n = force.shape[0]
    lengths = lengths or [n]
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    time_s = np.concatenate([np.arange(k) * 0.01 for k in lengths])
    pose = np.zeros((n, 6)) if pose is None else pose
    return SimState(0, 0, "St12C13", 0, CATALOGUES["single"]()[0], SENSOR, offsets=offsets, time_s=time_s,
                    pose_cmd=pose, pose_true=pose, force=force, flags=np.zeros(n, np.int64))


def test_prony_step_response():
    """A unit load ramped in over the first sample, then held: exact recursion vs the closed form."""
    dt, taus, g = 0.01, [0.5, 5.0], [0.15, 0.1]
    out = viscoelastic.relax(np.ones((2001, 1)), dt, taus, g)[:, 0]
    b = [tau / dt * (1 - math.exp(-dt / tau)) for tau in taus]
    for n in (0, 300, 2000):
        expect = 0.75 + sum(gi * bi * math.exp(-n * dt / tau) for gi, bi, tau in zip(g, b, taus))
        assert out[n] == pytest.approx(expect, rel=1e-9)
    assert out[0] == pytest.approx(1.0, abs=2e-3)                       # nearly the elastic force at once
    assert out[-1] == pytest.approx(0.75 + 0.1 * math.exp(-20 / 5.0), rel=1e-3)   # relaxed towards g_inf
    assert viscoelastic.relax(np.ones((5, 1)), dt, [0.5], [0.0])[-1, 0] == 1.0


def test_bristle_sticks_then_slips_at_coulomb():
    params = {**shear.DEFAULTS, "stiffness_n_per_mm": 1.0, "mu": 0.5}
    fn = np.full((6, 1), 2.0)
    du = np.array([[0, 0], [0.2, 0], [0.2, 0], [0.5, 0], [0.5, 0], [-0.3, 0]])
    ft = shear.bristle(fn, du, params)[:, 0, 0]
    # stick, stick, stick, slip (mu Fn = 1)
    np.testing.assert_allclose(ft, [0, -0.2, -0.4, -0.9, -1.0, -0.7])
    assert not shear.bristle(np.zeros((3, 1)), du[:3], params).any()     # no contact, no friction


def test_pad_frame_steps_follow_yaw():
    pose = np.zeros((2, 6))
    pose[1, 0] = 1.0
    pose[:, 5] = math.pi / 2
    np.testing.assert_allclose(shear.pad_frame_steps(pose)[1], [0.0, -1.0], atol=1e-12)


def test_crosstalk_neighbours_and_saturation():
    mix = sensor.crosstalk_matrix(TXY, 4.7, 0.1)
    neighbours = (mix > 0).sum(1) - 1
    assert neighbours.min() == 2 and neighbours.max() == 4 and sorted(set(neighbours)) == [2, 3, 4]
    force = np.zeros((1, 30, 3))
    force[0, :, 2] = 100.0
    st = state_with(force)
    out = sensor._sensor(st, {**sensor.DEFAULTS, "gain_sd": 0.0}, stream(0, 0, "sensor"))
    assert out.force.max() <= sensor.DEFAULTS["saturation_n"] and out.force.max() > 2.99
    counts = sensor._sensor(st, {**sensor.DEFAULTS, "counts_per_n": 10.0}, stream(0, 0, "sensor"))
    assert counts.force_units == "counts" and counts.info["counts_per_n"] == 10.0


def test_noise_white_level_and_baseline():
    force = np.zeros((4000, 30, 3))
    st = state_with(force, lengths=[2000, 2000])
    params = {**noise.DEFAULTS, "drift_n_per_s": 0.0, "offset_n": 0.0, "baseline": False, "white_n": 0.02}
    out = noise._noise(st, params, stream(0, 0, "noise"))
    assert out.force.std() == pytest.approx(0.02, rel=0.02)
    based = noise._noise(st, {**noise.DEFAULTS}, stream(0, 0, "noise"))
    assert not based.force[[0, 2000]].any() and based.time_s[2000] == 0
    assert (np.abs(based.time_s - st.time_s) < 0.0046).all()


def test_robot_and_handheld_tracking_errors():
    n = 300
    pose = np.zeros((n, 6))
    pose[:, 0] = np.linspace(0, 3, n)
    st = state_with(np.zeros((n, 30, 3)), pose)
    robot = pose_tracking._pose(st, pose_tracking.DEFAULTS, stream(0, 0, "pose")).pose_out
    assert np.std(robot[:, :3] - pose[:, :3]) == pytest.approx(0.1, rel=0.15)
    params = {**pose_tracking.DEFAULTS, "mode": "handheld", "jitter_mm": 0.0, "jitter_rad": 0.0,
              "calib_mm": 0.0, "calib_deg": 0.0, "bias_mm": 0.0}
    held = pose_tracking._pose(st, params, stream(0, 0, "pose")).pose_out
    changes = np.count_nonzero(np.diff(held[:, 0]))
    assert abs(changes - 3 * 30) <= 2                                   # 30 Hz over 3 s
    lag = pose[:, 0] - held[:, 0]
    # delay + half a sample, 1 mm/s
    assert lag[50:].mean() == pytest.approx((0.03 + 0.5 / 30) * 1.0, abs=0.01)


def test_tilt_flags_beyond_validity():
    pose = np.zeros((3, 6))
    pose[:, 3] = [0.0, math.radians(20), math.radians(80)]
    st = state_with(np.zeros((3, 30, 3)), pose)
    out = tilt._tilt(st, {**tilt.DEFAULTS, "mount_tilt_deg": 0.0, "yaw_error_deg": 0.0}, stream(0, 0, "tilt"))
    assert out.flags.tolist() == [0, 0, 1]
    assert tilt.tilt_rad(np.array([[0, 0, 0, 0.1, 0.2, 3.0]]))[0] == pytest.approx(
        math.acos(math.cos(0.1) * math.cos(0.2)))


def test_variability_casts_are_few_and_keyed_by_insert():
    params = {**variability.DEFAULTS, "variants": 2}
    st = state_with(np.zeros((1, 30, 3)))
    casts = {variability._cast(st, params, stream(0, i, "variability")).phantom.content_hash()
             for i in range(12)}
    assert len(casts) == 2 and st.phantom.content_hash() not in casts
    xy = np.random.default_rng(0).uniform(-30, 30, size=(20000, 2))
    field = variability.texture_field(xy, params, np.random.default_rng(1))
    assert field.mean() == pytest.approx(1.0, abs=0.01) and field.std() == pytest.approx(0.05, rel=0.3)


def test_rotate_pose_and_taxel_positions():
    pose = np.array([[10.0, 0.0, -1.0, 0.1, 0.2, 0.3]])
    r = rotate_pose(pose, 2)
    np.testing.assert_allclose(r[0], [0.0, 10.0, -1.0, 0.1, 0.2, 0.3 + math.pi / 2], atol=1e-12)
    np.testing.assert_allclose(rotate_pose(r, -2), pose, atol=1e-12)
    w = taxel_world_xy(np.array([[1.0, 2.0, 0, 0, 0, math.pi / 2]]), np.array([[1.0, 0.0]]))
    np.testing.assert_allclose(w[0, 0], [1.0, 3.0], atol=1e-12)
