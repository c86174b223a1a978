"""The surface frame: onsets from the forces, a robust plane per scan, poses on it (lesscli.data.surface)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lesscli.data import surface as sf
from lesscli.io.scans import ScanSet, default_meta
from lesscli.io.sensor import xela_uscu
from lesscli.sim.effects.surface import rig_pose

STIFF_N_PER_MM = 2.0           # total normal force per mm^1.5 of indentation


def pressed_scan(top, n_traj: int = 30, steps: int = 40, seed: int = 0, noise_n: float = 0.005,
                 bad: int = 0) -> ScanSet:
    """One scan of vertical presses from 4 mm above a top z = top(x, y) (flat pad, no tilt) to 1.5 mm into
    it; the normal force is STIFF (depth)^1.5 spread over the 30 taxels, plus white noise. ``bad`` touches
    carry a force offset from their first step on (they start in contact)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-20, 20, size=(n_traj, 2))
    h = top(xy[:, 0], xy[:, 1])
    z = h[:, None] + np.linspace(4.0, -1.5, steps)[None, :]
    pose = np.zeros((n_traj, steps, 6))
    pose[..., :2], pose[..., 2] = xy[:, None, :], z
    depth = np.clip(h[:, None] - z, 0, None)
    force = rng.normal(0, noise_n, size=(n_traj, steps, 30, 3))
    force[..., 2] += (STIFF_N_PER_MM * depth**1.5 / 30)[..., None]
    force[:bad, 1:, :, 2] += 0.5
    n = n_traj * steps
    return ScanSet(pose=pose.reshape(n, 6).astype(np.float32),
                   force=force.reshape(n, 30, 3).astype(np.float32),
                   time_s=np.tile(np.arange(steps) * 0.01, n_traj),
                   traj_offsets=np.arange(n_traj + 1, dtype=np.int64) * steps,
                   traj_scan=np.zeros(n_traj, np.int64), scan_insert=np.array(["St12C9"]),
                   scan_orientation=np.zeros(1, np.int64), scan_label=-np.ones(1, np.int64),
                   meta=default_meta(xela_uscu()))


def test_flat_top_off_the_frames_zero_is_found_within_the_onset_bias():
    """The force is first seen above the onset level (0.27 N here, 0.27 mm deep): the height found is that
    much low, the same at every height."""
    found = []
    for height in (-2.0, 0.0, 1.3):
        surf = sf.surfaces(pressed_scan(lambda x, y, h=height: np.full_like(x, h)))[0]
        assert surf.onsets == 30
        assert -0.3 < surf.a_mm - height < 0.0
        found.append(surf.a_mm - height)
        assert abs(surf.b) < 2e-3 and abs(surf.c) < 2e-3
    assert np.ptp(found) < 1e-5


def test_a_tilted_top_is_fitted_as_a_plane():
    surf = sf.surfaces(pressed_scan(lambda x, y: 0.5 + 0.03 * x - 0.02 * y))[0]
    assert -0.3 < surf.a_mm - 0.5 < 0.0
    assert (surf.b, surf.c) == pytest.approx((0.03, -0.02), abs=3e-3)


def test_a_few_touches_that_start_in_contact_do_not_move_the_surface():
    clean = sf.surfaces(pressed_scan(lambda x, y: np.zeros_like(x)))[0]
    dirty = sf.surfaces(pressed_scan(lambda x, y: np.zeros_like(x), bad=4))[0]
    assert dirty.onsets <= 30
    assert dirty.a_mm == pytest.approx(clean.a_mm, abs=0.05)


def test_shifting_the_rig_leaves_the_surface_frame_poses_unchanged():
    scans = pressed_scan(lambda x, y: 0.01 * x)
    shifted = scans.pose.astype(np.float64)
    shifted[:, 2] += 1.7
    a = sf.surface_frame(scans)
    b = sf.surface_frame(replace(scans, pose=shifted.astype(np.float32)))
    assert np.abs(a.pose - b.pose).max() < 1e-5
    assert a.meta["pose_frame"] == sf.FRAME and len(a.meta["surface"]) == 1
    assert sf.surface_frame(a) is a                      # already in its surface frame


def test_a_tilted_top_and_a_tilted_pad_give_the_depth_under_every_taxel():
    """rig_pose puts a pad on a tilted top; to_surface takes it back to first order in the slope."""
    rng = np.random.default_rng(1)
    pose = np.c_[rng.uniform(-20, 20, (50, 3)), rng.normal(0, 0.05, (50, 2)), rng.uniform(0, 1.4, 50)]
    back = sf.to_surface(rig_pose(pose, 1.2, 0.02, -0.015), sf.Surface(1.2, 0.02, -0.015, 30))
    assert np.abs(back - pose).max() < 2e-3


def test_no_contact_keeps_the_frames_zero_and_sparse_scans_still_find_the_top():
    scans = pressed_scan(lambda x, y: np.zeros_like(x))
    quiet = replace(scans,
                    force=np.random.default_rng(2).normal(0, 0.005, scans.force.shape).astype(np.float32))
    assert sf.surfaces(quiet)[0] == sf.Surface()
    sparse = pressed_scan(lambda x, y: np.full_like(x, 0.8), steps=8)   # 0.8 mm per step
    assert sf.surfaces(sparse)[0].a_mm == pytest.approx(0.8, abs=0.4)


def test_fewer_onsets_than_a_plane_needs_give_a_flat_surface_at_their_median():
    onsets = np.array([[0.0, 0.0, 1.0], [10.0, 0.0, 1.2], [0.0, 10.0, 0.9]])
    assert sf.fit_surface(onsets) == sf.Surface(1.0, 0.0, 0.0, 3)


def test_the_online_surface_reaches_the_batch_surface_once_every_touch_has_ended():
    scans = pressed_scan(lambda x, y: 0.6 + 0.02 * y)
    online = sf.OnlineSurface(scans.meta["sensor"], 30)
    first = online.push(scans.pose[0], scans.force[0], 0.0)
    assert first[2] == pytest.approx(scans.pose[0, 2])                  # nothing seen yet: the frame's zero
    for i in range(1, scans.n_steps):
        # live time runs on: touches end at lift-off
        online.push(scans.pose[i], scans.force[i], i * 0.01)
        if i == 39:                                                     # the first touch, before it ends
            top = 0.6 + 0.02 * scans.pose[0, 1]
            assert online.surface.onsets == 0 and -0.5 < online.surface.a_mm - top < 0.0
    online.push(scans.pose[0], scans.force[0], scans.n_steps * 0.01)      # lifted off: the last touch ends
    batch = sf.surfaces(scans)[0]
    assert (online.surface.a_mm, online.surface.b, online.surface.c) == pytest.approx(
        (batch.a_mm, batch.b, batch.c), abs=1e-9)
