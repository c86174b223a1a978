"""The scan-set format: round trip, selection, concatenation and every validation failure."""

import json

import numpy as np
import pytest
from factories import random_scanset

from lesscli.errors import DataError
from lesscli.io.scans import concat, load_scans, save_scans, to_arrays


def test_round_trip_preserves_every_array(tmp_path):
    scans = random_scanset(n_scans=3)
    save_scans(str(tmp_path / "a.npz"), scans)
    back = load_scans(str(tmp_path / "a.npz"))
    for key, value in to_arrays(scans).items():
        if key != "meta":
            np.testing.assert_array_equal(to_arrays(back)[key], value, err_msg=key)
    assert back.meta["schema"] == "less.scans" and back.meta["sensor"]["taxels"] == 30


def test_scan_steps_cover_their_trajectories():
    scans = random_scanset(n_scans=3, traj_per_scan=2)
    offsets = scans.scan_step_offsets()
    assert offsets[0] == 0 and offsets[-1] == scans.n_steps
    assert offsets[1] == scans.traj_offsets[2]


def test_select_scans_keeps_labels_in_step():
    scans = random_scanset(n_scans=3)
    sub = scans.select_scans(np.array([2, 0]))
    assert list(sub.scan_insert) == [scans.scan_insert[2], scans.scan_insert[0]]
    np.testing.assert_array_equal(sub.label_of(0).data, scans.label_of(2).data)
    np.testing.assert_array_equal(sub.pose[: sub.scan_steps(0).stop], scans.pose[scans.scan_steps(2)])


def test_select_steps_drops_emptied_trajectories():
    scans = random_scanset(n_scans=1, traj_per_scan=3)
    keep = np.zeros(scans.n_steps, bool)
    keep[scans.traj_offsets[1]] = True
    sub = scans.select_steps(keep)
    assert sub.n_traj == 1 and sub.n_steps == 1


def test_concat_deduplicates_identical_labels():
    a = random_scanset(n_scans=2, seed=1)
    both = concat([a, a])
    assert both.n_scans == 4 and len(both.labels) == 2
    assert list(both.scan_label) == [0, 1, 0, 1]


def test_concat_refuses_different_sensors():
    a, b = random_scanset(), random_scanset()
    b.meta = {**b.meta, "sensor": {**b.meta["sensor"], "name": "other"}}
    with pytest.raises(DataError, match="sensor"):
        concat([a, b], names=["a.npz", "b.npz"])


def _write_raw(path, arrays):
    np.savez(path, **arrays)
    return str(path)


@pytest.mark.parametrize("mutate, message", [
    (lambda a: a.update(force=a["force"][:, :, :2]),
     r"'force' has shape \(\d+, 30, 2\), expected \(N, T, 3\)"),
    (lambda a: a["force"].__setitem__((3, 0, 2), np.nan), "'force' has NaN or inf at step 3"),
    (lambda a: a.update(meta=np.array(json.dumps({**json.loads(str(a["meta"])), "version": 9}))),
     "unsupported less.scans version 9"),
    (lambda a: a.pop("pose"), "missing key 'pose'"),
    (lambda a: a.update(traj_offsets=a["traj_offsets"][::-1]), "traj_offsets"),
    (lambda a: a.update(label_data=a["label_data"] + 7), "label codes must be 0..3"),
])
def test_validation_names_file_and_problem(tmp_path, mutate, message):
    arrays = to_arrays(random_scanset())
    mutate(arrays)
    path = _write_raw(tmp_path / "bad.npz", arrays)
    with pytest.raises(DataError, match=message) as err:
        load_scans(path)
    assert str(err.value).startswith(path)


def test_pickled_object_is_refused(tmp_path):
    arrays = to_arrays(random_scanset())
    arrays["force"] = np.array([{"a": 1}], dtype=object)
    path = _write_raw(tmp_path / "pickled.npz", arrays)
    with pytest.raises(DataError, match="pickled Python object"):
        load_scans(path)


def test_truncated_file_is_refused(tmp_path, scanset_file):
    data = scanset_file.read_bytes()
    bad = tmp_path / "trunc.npz"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="truncated or corrupt"):
        load_scans(str(bad))


def test_directory_of_shards_loads_as_one(tmp_path):
    (tmp_path / "shards").mkdir()
    save_scans(str(tmp_path / "shards" / "0.npz"), random_scanset(seed=1))
    save_scans(str(tmp_path / "shards" / "1.npz"), random_scanset(seed=2))
    assert load_scans(str(tmp_path / "shards")).n_scans == 4


def test_saving_and_loading_make_no_full_size_copy_of_the_steps(tmp_path):
    """Validation casts and checks in place or in blocks: writing and reading a scan set allocate far
    less than its force array (a full float64 copy, the old cost, would be twice it)."""
    import tracemalloc

    scans = random_scanset(n_scans=1, traj_per_scan=1)
    n = 400_000
    big = type(scans)(pose=np.zeros((n, 6), np.float32), force=np.ones((n, scans.n_taxels, 3), np.float32),
                      time_s=np.zeros(n), traj_offsets=np.array([0, n], np.int64),
                      traj_scan=np.zeros(1, np.int64), scan_insert=scans.scan_insert,
                      scan_orientation=scans.scan_orientation, scan_label=scans.scan_label,
                      labels=scans.labels, meta=scans.meta)
    path = str(tmp_path / "big.npz")
    for run in (lambda: save_scans(path, big, compress=False), lambda: load_scans(path)):
        tracemalloc.start()
        out = run()
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        allocated_by_result = 0 if out is None else out.pose.nbytes + out.force.nbytes
        assert peak - allocated_by_result < 0.25 * big.force.nbytes, (peak, big.force.nbytes)
