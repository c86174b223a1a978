"""Re-palpations of chosen insert-orientation pairs (examples/pairs.py, the density study's sets)."""

from __future__ import annotations

import json

import numpy as np
from factories import example_script, random_scanset

from lesscli.io.scans import load_scans, save_scans


def _sets():
    # source pairs (C, 0), (B, 1), (A, 2), (A, 3); reference pairs (A, 0), (B, 1), (X, 2)
    src = random_scanset(4, seed=1, inserts=["C", "B", "A", "A"])
    ref = random_scanset(3, seed=2, inserts=["A", "B", "X"])
    return src, ref


def test_keeps_a_scan_only_where_both_insert_and_orientation_match():
    pairs = example_script("pairs")
    src, ref = _sets()
    out = pairs.scans_of_pairs(src, pairs.pairs(ref))
    assert out.scan_insert.tolist() == ["B"]                 # A is in the reference at orientation 0 only
    assert out.scan_orientation.tolist() == [1]
    trajs = np.flatnonzero(src.traj_scan == 1)             # scan 1's steps, as they were
    steps = slice(src.traj_offsets[trajs[0]], src.traj_offsets[trajs[-1] + 1])
    np.testing.assert_array_equal(out.force, src.force[steps])
    np.testing.assert_array_equal(out.pose, src.pose[steps])


def test_the_script_writes_the_set_and_reports_the_pairs_it_lacks(tmp_path, capsys):
    pairs = example_script("pairs")
    src, ref = _sets()
    save_scans(str(tmp_path / "src.npz"), src)
    save_scans(str(tmp_path / "ref.npz"), ref)
    out = tmp_path / "out.npz"
    assert pairs.main([str(tmp_path / "src.npz"), "--of", str(tmp_path / "ref.npz"), "-o", str(out)]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record == {"file": str(out), "scans": 1, "of": 4, "pairs_missing": 2}
    kept = load_scans(str(out))
    assert kept.scan_insert.tolist() == ["B"]
    given = f"{tmp_path / 'src.npz'} --of {tmp_path / 'ref.npz'} -o {out}"
    assert kept.meta["history"][-1]["script"] == f"examples/pairs.py {given}"


def test_no_matching_scan_is_a_one_line_error_and_no_file(tmp_path, capsys):
    pairs = example_script("pairs")
    src = random_scanset(2, seed=1, inserts=["C", "D"])
    save_scans(str(tmp_path / "src.npz"), src)
    save_scans(str(tmp_path / "ref.npz"), random_scanset(2, seed=2, inserts=["A", "B"]))
    out = tmp_path / "out.npz"
    assert pairs.main([str(tmp_path / "src.npz"), "--of", str(tmp_path / "ref.npz"), "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "src.npz" in err[0] and "insert and orientation" in err[0]
    assert not out.exists()


def test_an_unreadable_reference_is_one_line_naming_it_and_no_file(tmp_path, capsys):
    pairs = example_script("pairs")
    save_scans(str(tmp_path / "src.npz"), random_scanset(2, seed=1))
    (tmp_path / "ref.npz").write_bytes(b"junk")
    out = tmp_path / "out.npz"
    for ref in (tmp_path / "ref.npz", tmp_path / "missing.npz"):
        assert pairs.main([str(tmp_path / "src.npz"), "--of", str(ref), "-o", str(out)]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"pairs.py: {ref}:") and "src.npz" not in err[0]
    assert not out.exists()
