"""[effects.surface]: the top off the frame's zero and tilted per scan, a slow baseline drift; absent,
nothing."""

from __future__ import annotations

import sys
import tomllib

import numpy as np
import pytest
from factories import TINY_SCENE

from lesscli.data.surface import surface_frame
from lesscli.sim.effects.surface import scan_time_s
from lesscli.sim.scene import parse_scene
from lesscli.sim.simulate import simulate


def _scans(extra: str = ""):
    return simulate(parse_scene(tomllib.loads(TINY_SCENE + extra), "tiny"))


def test_off_the_effect_is_never_imported_and_on_it_moves_only_the_recorded_poses():
    sys.modules.pop("lesscli.sim.effects.surface", None)
    plain = _scans()
    assert "lesscli.sim.effects.surface" not in sys.modules
    shifted = _scans("[effects.surface]\noffset_mm = 2.0\ntilt_deg = 0.0\ndrift_n_per_s = 0.0\n")
    np.testing.assert_array_equal(plain.force, shifted.force)           # the same physics and noise
    np.testing.assert_array_equal(plain.pose[:, [0, 1, 3, 4, 5]], shifted.pose[:, [0, 1, 3, 4, 5]])
    dz = shifted.pose[:, 2].astype(np.float64) - plain.pose[:, 2]
    offsets = shifted.scan_step_offsets()
    per_scan = [dz[offsets[s]:offsets[s + 1]] for s in range(shifted.n_scans)]
    assert all(np.ptp(d) < 1e-5 and abs(d[0]) <= 2.0 for d in per_scan)
    assert len({round(float(d[0]), 3) for d in per_scan}) == shifted.n_scans   # one draw per scan
    # the surface frame undoes the shift
    assert np.abs(surface_frame(plain).pose - surface_frame(shifted).pose).max() < 1e-4


def test_tilt_and_drift_change_the_poses_slopes_and_the_normal_forces_only():
    plain = _scans()
    rig = _scans("[effects.surface]\noffset_mm = 0.0\ntilt_deg = 2.0\ndrift_n_per_s = 0.05\n")
    assert np.abs(rig.pose[:, 3:5] - plain.pose[:, 3:5]).max() > 1e-3
    np.testing.assert_array_equal(rig.force[..., :2], plain.force[..., :2])
    assert np.abs(rig.force[..., 2] - plain.force[..., 2]).max() > 1e-3


def test_scan_time_runs_on_across_trajectories():
    t = scan_time_s(np.array([0.0, 0.01, 0.02, 0.0, 0.01]), np.array([0, 3, 5]))
    np.testing.assert_allclose(t, [0.0, 0.01, 0.02, 0.03, 0.04])


def test_bad_parameters_are_refused():
    from lesscli.errors import DataError

    with pytest.raises(DataError, match="effects.surface"):
        _scans("[effects.surface]\ntilt_deg = -1.0\n")
