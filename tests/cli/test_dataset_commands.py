"""Dataset commands: subsample, concat, split, info; the acceptance pipeline; bad inputs."""

import json
import os
import zipfile

import numpy as np
import pytest
from factories import random_scanset
from published_fixture import break_file, write_root

from lesscli.data.ops import pick_trajectories, split, step_index_in_trajectory, subsample
from lesscli.errors import DataError
from lesscli.io.scans import load_scans, save_scans, to_arrays


def test_subsample_every_keeps_each_trajectorys_first_step():
    scans = random_scanset(n_scans=2, traj_per_scan=3, max_len=12, seed=4)
    sub = subsample(scans, every=3)
    expected = (scans.traj_lengths() + 2) // 3
    np.testing.assert_array_equal(sub.traj_lengths(), expected)
    np.testing.assert_array_equal(sub.pose[sub.traj_offsets[:-1]], scans.pose[scans.traj_offsets[:-1]])
    keep = step_index_in_trajectory(scans) % 3 == 0
    np.testing.assert_array_equal(sub.force, scans.force[keep])
    assert sub.meta["sample_rate_hz"] == pytest.approx(100 / 3)


def test_subsample_max_length_and_trajectories_per_scan():
    scans = random_scanset(n_scans=3, traj_per_scan=5, max_len=20, seed=1)
    sub = subsample(scans, every=2, max_length=3)
    assert sub.traj_lengths().max() <= 3
    np.testing.assert_array_equal(sub.traj_lengths(), np.minimum((scans.traj_lengths() + 1) // 2, 3))
    picked = subsample(scans, trajectories=2, rng=np.random.default_rng(7))
    assert np.bincount(picked.traj_scan).tolist() == [2, 2, 2]
    again = subsample(scans, trajectories=2, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(picked.pose, again.pose)
    other = [pick_trajectories(scans, 2, np.random.default_rng(s)) for s in range(6)]
    assert len({m.tobytes() for m in other}) > 1  # the seed matters
    assert subsample(scans, trajectories=9, rng=np.random.default_rng(0)).n_traj == scans.n_traj


def _inserts(part):
    return set(part.scan_insert.tolist())


def test_split_by_insert_never_shares_an_insert():
    inserts = [f"St{10 + i}C{i}" for i in range(10)]
    scans = random_scanset(n_scans=20, traj_per_scan=1, inserts=inserts + inserts, seed=2)
    parts = split(scans, "insert", test=0.2, val=0.1, rng=np.random.default_rng(0))
    assert list(parts) == ["train", "val", "test"]
    assert [len(_inserts(p)) for p in parts.values()] == [7, 1, 2]
    assert not (_inserts(parts["train"]) & _inserts(parts["test"]))
    assert not (_inserts(parts["val"]) & (_inserts(parts["train"]) | _inserts(parts["test"])))
    assert sum(p.n_scans for p in parts.values()) == 20 and parts["test"].n_scans == 4


def test_split_by_scan_and_too_few_groups():
    scans = random_scanset(n_scans=5, traj_per_scan=1, inserts=["A"] * 5)
    parts = split(scans, "scan", test=0.2, val=0.0, rng=np.random.default_rng(0))
    assert list(parts) == ["train", "test"] and parts["test"].n_scans == 1
    with pytest.raises(DataError, match="1 insert"):
        split(scans, "insert", test=0.2, val=0.0, rng=np.random.default_rng(0), name="x.npz")


def test_cli_split_writes_files_and_records(run_less, tmp_path):
    scans = random_scanset(n_scans=6, traj_per_scan=1, inserts=[f"I{i}" for i in range(6)])
    save_scans(str(tmp_path / "s.npz"), scans)
    proc = run_less("split", "s.npz", "--test", "0.34", "--val", "0.17", "--seed", "3", "-o", "out",
                    check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [r["split"] for r in rows] == ["train", "val", "test"]
    assert sorted(os.listdir(tmp_path / "out")) == ["test.npz", "train.npz", "val.npz"]
    assert [r["scans"] for r in rows] == [3, 1, 2]
    loaded = {r["split"]: load_scans(str(tmp_path / "out" / f"{r['split']}.npz")) for r in rows}
    assert set().union(*(_inserts(p) for p in loaded.values())) == {f"I{i}" for i in range(6)}
    assert loaded["test"].meta["history"][-1]["split"] == "test"


def test_cli_concat_checks_and_deduplicates(run_less, tmp_path):
    a = random_scanset(n_scans=2, seed=1)
    save_scans(str(tmp_path / "a.npz"), a)
    run_less("concat", "a.npz", "a.npz", "-o", "aa.npz", check=True)
    both = load_scans(str(tmp_path / "aa.npz"))
    assert both.n_scans == 4 and len(both.labels) == 2
    b = random_scanset(n_scans=1)
    b.meta = {**b.meta, "units": {**b.meta["units"], "force": "counts"}}
    save_scans(str(tmp_path / "b.npz"), b)
    proc = run_less("concat", "a.npz", "b.npz", "-o", "ab.npz")
    assert proc.returncode == 1 and b"b.npz: 'units' differs" in proc.stderr
    assert not (tmp_path / "ab.npz").exists()
    c = random_scanset(n_scans=1, seed=2)
    c.meta = {**c.meta, "sample_rate_hz": 10.0}
    save_scans(str(tmp_path / "c.npz"), c)
    run_less("concat", "a.npz", "c.npz", "-o", "ac.npz", check=True)
    mixed = load_scans(str(tmp_path / "ac.npz"))
    assert mixed.n_scans == 3 and mixed.meta["sample_rate_hz"] is None
    assert np.array_equal(mixed.time_s[-c.n_steps:], c.time_s)
    assert both.meta["sample_rate_hz"] == a.meta["sample_rate_hz"]


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """``less import`` of the fixture root (module-wide: the acceptance pipeline starts here)."""
    import subprocess
    import sys
    from pathlib import Path

    base = tmp_path_factory.mktemp("accept")
    write_root(str(base / "root"))
    less = Path(sys.executable).parent / "less"
    subprocess.run([str(less), "import", "root", "-o", "a.npz"], cwd=base, check=True, capture_output=True)
    return base


def test_acceptance_pipeline_file_and_pipe_give_the_same_info(imported, run_less):
    cwd = imported
    run_less("subsample", "a.npz", "--every", "50", "-o", "b.npz", cwd=cwd, check=True)
    from_file = run_less("info", "b.npz", cwd=cwd, check=True).stdout
    piped = run_less("subsample", "a.npz", "--every", "50", "-o", "-", cwd=cwd, check=True).stdout
    from_pipe = run_less("info", "-", input=piped, cwd=cwd, check=True).stdout
    assert from_file == from_pipe
    info = json.loads(from_file)
    assert info["scans"] == 4 and info["steps_per_trajectory"]["max"] == 4 and info["sample_rate_hz"] == 2.0
    assert [h["command"].split()[1] for h in info["history"]] == ["import", "subsample"]
    full = json.loads(run_less("info", "b.npz", "--full-history", cwd=cwd, check=True).stdout)
    assert "-o b.npz" in full["history"][-1]["command"] and full["history"][-1]["time"]


def _bad_scansets(tmp_path):
    good = to_arrays(random_scanset())
    np.savez(tmp_path / "good.npz", **good)
    raw = (tmp_path / "good.npz").read_bytes()
    (tmp_path / "truncated.npz").write_bytes(raw[: len(raw) // 2])
    np.savez(tmp_path / "pickled.npz", **{**good, "pose": np.array([{"x": 1}], dtype=object)})
    nan = {**good, "force": good["force"].copy()}
    nan["force"][2, 5, 1] = np.nan
    np.savez(tmp_path / "nan.npz", **nan)
    np.savez(tmp_path / "shape.npz", **{**good, "force": good["force"].reshape(len(good["force"]), 90)})
    meta = json.loads(str(good["meta"]))
    np.savez(tmp_path / "version.npz", **{**good, "meta": np.array(json.dumps({**meta, "version": 2}))})
    return {"truncated.npz": "truncated or corrupt", "pickled.npz": "pickled Python object",
            "nan.npz": "'force' has NaN or inf at step 2", "shape.npz": r"'force' has shape \(\d+, 90\)",
            "version.npz": "unsupported less.scans version 2"}


def test_bad_inputs_exit_1_with_one_line_and_no_output(run_less, tmp_path):
    import re

    cases = _bad_scansets(tmp_path)
    assert zipfile.is_zipfile(tmp_path / "good.npz")
    for name, pattern in cases.items():
        proc = run_less("subsample", name, "--every", "2", "-o", "out.npz")
        err = proc.stderr.decode()
        assert proc.returncode == 1, (name, err)
        assert len(err.strip().splitlines()) == 1 and err.startswith(f"less: error: {name}"), (name, err)
        assert re.search(pattern, err), (name, err)
        assert "Traceback" not in err and proc.stdout == b""
        assert sorted(os.listdir(tmp_path)) == sorted([*cases, "good.npz"])  # no out.npz, no temp file


def test_hdf5_missing_robot_position_exit_1_no_output(run_less, tmp_path):
    root = write_root(str(tmp_path / "root"), n_traj=2)
    break_file(os.path.join(root, "poke_trial", "phantomA_St10D5_1.hdf5"))
    proc = run_less("import", "root", "-o", "a.npz")
    err = proc.stderr.decode()
    assert proc.returncode == 1 and len(err.strip().splitlines()) == 1
    assert "phantomA_St10D5_1.hdf5: traj_1: missing dataset 'robot/ee_position'" in err
    assert not (tmp_path / "a.npz").exists() and not [f for f in os.listdir(tmp_path)
                                                      if f.startswith(".a.npz")]
    proc = run_less("import", "root", "-o", "a.npz", "--on-error", "skip")
    assert proc.returncode == 0 and load_scans(str(tmp_path / "a.npz")).n_scans == 3
    assert b"skipped" in proc.stderr or b"skipped" in proc.stdout


def test_subsample_tolerates_empty_trajectories_anywhere():
    from dataclasses import replace

    scans = random_scanset(n_scans=1, traj_per_scan=2, seed=3)
    n, mid = scans.n_steps, int(scans.traj_offsets[1])
    holey = replace(scans, traj_offsets=np.array([0, 0, mid, n, n]), traj_scan=np.zeros(4, np.int64),
                    traj_attrs={})
    holey.__post_init__()
    sub = subsample(holey, every=2)
    np.testing.assert_array_equal(sub.traj_lengths(), (scans.traj_lengths() + 1) // 2)
