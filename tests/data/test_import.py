"""Import of the published HDF5 layout: preprocessing steps with hand-derived values, then whole files."""

import json
import os

import h5py
import numpy as np
import pytest
from published_fixture import (
    REF_POS_M,
    REF_ROT,
    break_file,
    rot_x,
    rot_z,
    write_hand_held_root,
    write_root,
)

from lesscli.data import preprocess as pp
from lesscli.data.published import ImportOptions, import_published, label_volume
from lesscli.errors import DataError
from lesscli.io.scans import load_scans

# ---------------------------------------------------------------------------------------------- unit steps


def test_onset_index_forward_window():
    # z still until t = 1 s, then down at 5 mm/s; forward speed over 0.2 s is 25 (t - 0.8) mm/s on
    # [0.8, 1], which first exceeds 2 mm/s after t = 0.88 s: the sample at t = 0.885 s (index 88).
    t = 0.005 + 0.01 * np.arange(200)
    z = -5.0 * np.clip(t - 1.0, 0, None)
    assert pp.onset_index(t, z) == 88


def test_onset_index_none_when_never_moving_fast_enough():
    t = np.arange(100) * 0.01
    assert pp.onset_index(t, 1.9 * t) is None  # 1.9 mm/s everywhere
    assert pp.onset_index(t, 2.1 * t) == 0


def test_recentre_by_hand():
    # reference at (1, 2, 3) turned 90 deg about z: the world +y axis is the reference +x axis
    pos, rot = pp.recentre(np.array([[1.0, 3.0, 3.0], [1.0, 2.0, 5.0]]), np.stack([rot_z(np.pi / 2)] * 2),
                           np.array([1.0, 2.0, 3.0]), rot_z(np.pi / 2))
    np.testing.assert_allclose(pos, [[1.0, 0.0, 0.0], [0.0, 0.0, 2.0]], atol=1e-12)
    np.testing.assert_allclose(rot[0], np.eye(3), atol=1e-12)


def test_baseline_removal_subtracts_first_sample():
    force = np.array([[[1.0, 2.0, 10.0]], [[3.0, 5.0, 7.0]]])
    np.testing.assert_allclose(pp.remove_baseline(force), [[[0, 0, 0]], [[2, 3, -3]]])


def test_label_rotation_by_hand():
    img = np.zeros((1, 5, 5), np.uint8)
    img[0, 2, 4] = 3  # x = +2, y = 0 relative to the centre (column 4, row 2)
    out = pp.rotate_label(img, -90.0)  # (2, 0) -> R(-90)(2, 0) = (0, -2): column 2, row 0
    assert out[0, 0, 2] == 3 and out.sum() == 3
    assert np.array_equal(pp.rotate_label(img, -45.0 * 8), img)
    half = np.zeros((1, 9, 9), np.uint8)
    half[0, :, 5:] = 1  # x > 0
    out = pp.rotate_label(half, -45.0)  # becomes the half-plane x > y (y along rows)
    assert out[0, 4 + 1, 4 + 2] == 1 and out[0, 4 + 2, 4 + 1] == 0  # (x=2, y=1) in, (x=1, y=2) out
    assert out[0, 4 - 3, 4 + 3] == 1 and out[0, 4 + 3, 4 - 3] == 0


def test_label_codes_and_geometry():
    raw = np.zeros((26, 128, 128), np.uint8)
    raw[25, 64, 100] = 255  # top slice, canvas x = (100 - 63.5) * 0.4774 = +17.4 mm, y = +0.24 mm
    raw[0, 0, 0] = 200
    raw[5, 5, 5] = 127
    vol = label_volume(raw, "St12C13", 2, "st12c13_0.npy")
    assert sorted(np.unique(vol.data).tolist()) == [0, 1, 2, 3]
    np.testing.assert_allclose(vol.spacing_mm, [0.9, 0.4774, 0.4774])
    np.testing.assert_allclose(vol.origin_mm, [-22.5, -63.5 * 0.4774, -63.5 * 0.4774])
    k, i, j = np.argwhere(vol.data == 3)[0]
    z, y, x = vol.origin_mm + np.array([k, i, j]) * vol.spacing_mm
    # canvas (17.4, 0.24) rotated by -90 deg -> (0.24, -17.4); mirrored in x -> pose (-0.24, -17.4)
    assert (z == pytest.approx(0.0) and x == pytest.approx(-0.24, abs=0.5)
            and y == pytest.approx(-17.4, abs=0.5))
    flipped = label_volume(raw, "St12C13", 2, "st12c13_0.npy", top_slice="first")
    assert np.argwhere(flipped.data == 3)[0][0] == 0  # the stored top slice now sits deepest
    big = label_volume(raw, "bst12d30", 0, "bst12d30_0.npy")
    np.testing.assert_allclose(big.spacing_mm, [0.9, 0.9548, 0.9548])
    with pytest.raises(DataError, match="unexpected label values"):
        label_volume(raw + 1, "St12C13", 0, "x.npy")


def test_calibration_maps_estimates_to_robot_frame():
    calib = {"r_pos": rot_z(np.pi / 2), "t_pos": np.array([1.0, 0, 0]), "R_ori": rot_x(np.pi / 2)}
    pos, rot = pp.calibrate_estimate(np.array([[1.0, 0, 0]]), np.eye(3)[None], calib)
    np.testing.assert_allclose(pos, [[1.0, 1.0, 0.0]], atol=1e-12)  # p r^T + t = (0, 1, 0) + (1, 0, 0)
    np.testing.assert_allclose(rot[0], rot_x(np.pi / 2), atol=1e-12)


# ---------------------------------------------------------------------------------------------- whole files


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return write_root(str(tmp_path_factory.mktemp("published")))


def test_import_recovers_the_fixture_poses_and_forces(root):
    records = []
    scans = import_published(root, ImportOptions(), report=records.append)
    assert scans.n_scans == 4 and scans.n_traj == 12
    assert [r["status"] for r in records] == ["ok"] * 4
    assert scans.meta["units"]["force"] == "counts"
    first = scans.pose[scans.traj_offsets[0]:scans.traj_offsets[1]]
    # traj_0 sits at reference-frame (-10, 5) mm, yaw 0, starting 2 mm above the surface and going 8 mm deep
    np.testing.assert_allclose(first[:, :2], [[-10.0, 5.0]] * len(first), atol=1e-6)
    np.testing.assert_allclose(first[:, 3:], 0.0, atol=1e-6)
    assert first[0, 2] == pytest.approx(2.0, abs=0.01) and first[:, 2].min() == pytest.approx(-6.0, abs=0.05)
    # onset: forward speed 40 (t - 0.2) mm/s first exceeds 2 at robot sample t = 0.252 s -> sensor t = 0.26 s;
    # the overlap ends at the robot's last sample, 1.996 s -> sensor samples 0.26 .. 1.99 s: 174 steps
    assert scans.traj_lengths()[0] == 174
    second = scans.pose[scans.traj_offsets[1]:scans.traj_offsets[2]]
    np.testing.assert_allclose(second[:, 5], 0.2, atol=1e-6)  # yaw recovered after recentring
    np.testing.assert_allclose(scans.force[scans.traj_offsets[:-1]], 0.0)  # baseline removed
    assert scans.force[..., 2].max() > 700  # 6 mm of contact at 150 counts/mm (minus the baseline noise)
    np.testing.assert_allclose(scans.traj_attrs["yaw_rad"][:3], [0.0, 0.2, 0.4], atol=1e-6)
    assert scans.traj_attrs["primitive"].tolist().count("jab") == 3
    assert len(scans.labels) == 4 and all(v.shape == (26, 128, 128) for v in scans.labels)


def test_import_every_trajectories_and_shards(root):
    sub = import_published(root, ImportOptions(every=50, trajectories=2))
    assert sub.n_traj == 8 and set(sub.traj_lengths().tolist()) == {4}  # ceil(174 / 50)
    assert sub.meta["sample_rate_hz"] == 2.0
    parts = [import_published(root, ImportOptions(), shard=(i, 3)) for i in range(3)]
    assert sum(p.n_scans for p in parts) == 4
    inserts = sorted(name for p in parts for name in p.scan_insert.tolist())
    assert inserts == ["St10D5", "St10D5", "St12C13", "St12C13"]


def test_hand_held_import_matches_robot_poses(tmp_path):
    hh = write_hand_held_root(str(tmp_path / "hh"))
    robot = import_published(hh, ImportOptions())
    tracked = import_published(hh, ImportOptions(hand_held=True))
    np.testing.assert_allclose(tracked.pose, robot.pose, atol=1e-4)
    assert tracked.meta["source"]["hand_held"] is True
    os.remove(os.path.join(hh, "est_to_robot_calibration.npz"))
    with pytest.raises(DataError, match="est_to_robot_calibration.npz"):
        import_published(hh, ImportOptions(hand_held=True))


def test_over_long_and_short_trajectories_are_dropped_not_truncated(tmp_path):
    root = write_root(str(tmp_path / "r"), n_traj=2)
    path = os.path.join(root, "poke_trial", "phantomA_St12C13_0.hdf5")
    with h5py.File(path, "a") as h5:
        for key in ("xela/data", "xela/timestamps"):
            data = h5[f"traj_1/{key}"][()][:8]
            del h5[f"traj_1/{key}"]
            h5[f"traj_1/{key}"] = data
    records = []
    import_published(root, ImportOptions(), report=records.append)
    rec = next(r for r in records if r["file"].endswith("St12C13_0.hdf5"))
    assert rec["trajectories"] == 1 and rec["dropped"] == {"short": 1, "no_onset": 0, "too_long": 0}
    stream = pp.Stream(np.arange(600) * 0.01, np.zeros((600, 30, 3)), np.arange(600) * 0.01,
                       np.c_[np.zeros((600, 2)), -0.01 * np.arange(600) * 0.01], np.stack([np.eye(3)] * 600))
    assert pp.preprocess(stream, np.zeros(3), np.eye(3))[1] == "too_long"
    assert pp.preprocess(stream, np.zeros(3), np.eye(3), max_steps=600)[0].pose.shape == (600, 6)


def test_broken_file_fails_or_is_skipped_by_name(tmp_path):
    root = write_root(str(tmp_path / "r"), n_traj=2)
    bad = os.path.join(root, "poke_trial", "phantomA_St12C13_2.hdf5")
    break_file(bad)
    with pytest.raises(DataError,
                       match=r"phantomA_St12C13_2\.hdf5: traj_1: missing dataset 'robot/ee_position'"):
        import_published(root, ImportOptions())
    records = []
    scans = import_published(root, ImportOptions(), on_error="skip", report=records.append)
    assert scans.n_scans == 3
    skipped = [r for r in records if r["status"] == "skipped"]
    assert (len(skipped) == 1 and "St12C13_2" in skipped[0]["file"]
            and "robot/ee_position" in skipped[0]["error"])


def test_inconsistent_timestamps_are_an_error(tmp_path):
    root = write_root(str(tmp_path / "r"), n_traj=1)
    path = os.path.join(root, "poke_trial", "phantomA_St10D5_1.hdf5")
    with h5py.File(path, "a") as h5:
        t = h5["traj_0/robot/timestamps"][()]
        t[50] = t[10]
        h5["traj_0/robot/timestamps"][...] = t
    with pytest.raises(DataError,
                       match="St10D5_1.hdf5: traj_0: 'robot/timestamps' is not finite and non-decreasing"):
        import_published(root, ImportOptions())


def test_cli_import_writes_records_and_a_valid_scan_set(root, run_less, tmp_path):
    proc = run_less("import", root, "-o", tmp_path / "a.npz", "--every", "10", check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [r["status"] for r in rows] == ["ok"] * 4 and rows[0]["file"].startswith("poke_trial")
    scans = load_scans(str(tmp_path / "a.npz"))
    assert scans.n_scans == 4 and scans.meta["history"][-1]["command"].startswith("less import")
    np.testing.assert_allclose(REF_ROT.T @ REF_ROT, np.eye(3), atol=1e-12)  # fixture sanity
    assert REF_POS_M.shape == (3,)


def test_counts_per_newton_converts_and_records_the_calibration(root, run_less, tmp_path):
    run_less("import", root, "-o", "c.npz", check=True, cwd=tmp_path)
    run_less("import", root, "-o", "n.npz", "--counts-per-newton", "150", check=True, cwd=tmp_path)
    from lesscli.data.surface import surfaces
    from lesscli.io.scans import load_scans

    counts, newtons = load_scans(str(tmp_path / "c.npz")), load_scans(str(tmp_path / "n.npz"))
    assert counts.meta["units"]["force"] == "counts" and "counts_per_n" not in counts.meta["sensor"]
    assert newtons.meta["units"]["force"] == "N" and newtons.meta["sensor"]["counts_per_n"] == 150.0
    assert "150 counts per N" in newtons.meta["source"]["force"]
    np.testing.assert_allclose(newtons.force, counts.force / 150.0, rtol=1e-6, atol=1e-6)
    # the fixture's pad starts 2 mm above a top at the reference frame's zero: its touches find it there
    for scans in (counts, newtons):
        assert all(-0.5 < s.a_mm <= 0.0 and s.onsets == 3 for s in surfaces(scans))
    bad = run_less("import", root, "-o", "x.npz", "--counts-per-newton", "0", cwd=tmp_path)
    assert bad.returncode == 2 and not (tmp_path / "x.npz").exists()
