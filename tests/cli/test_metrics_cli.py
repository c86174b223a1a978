"""``less metrics`` and ``less bench metrics`` through the installed console script."""

import json

import numpy as np
import pytest
from factories import random_scanset, sphere_labels

from lesscli.io.labels import INCLUSION, INSERT, LabelVolume, save_nifti
from lesscli.io.predictions import PredictionSet, ScanPrediction, save_predictions
from lesscli.io.scans import save_scans
from lesscli.metrics import score_labels

SHAPE = (6, 24, 24)
SPACING = (0.9, 0.5, 0.5)


def _truth(centre_mm, radius_mm=2.5):
    return sphere_labels(center_mm=centre_mm, radius_mm=radius_mm, shape=SHAPE, spacing=SPACING)


def _onehot(labels):
    return np.eye(4, dtype=np.float32)[labels].transpose(3, 0, 1, 2)


def write_preds(path, shifts, seed=0, model="less", probs_scale=1.0):
    """A prediction file: scan s has a sphere truth and the same sphere shifted by shifts[s] voxels in x."""
    scans = []
    for s, shift in enumerate(shifts):
        truth = _truth((-2.0, 1.0 * s, -1.0))
        pred = np.roll(truth.data, shift, axis=2)
        probs = probs_scale * _onehot(pred) + (1 - probs_scale) * _onehot(np.full(SHAPE, INSERT))
        scans.append(ScanPrediction(probs=probs, origin_mm=truth.origin_mm, spacing_mm=truth.spacing_mm,
                                    truth=truth.data, insert=f"St1{s}C5", orientation=s, steps=10))
    meta = {"dim": 3, "threshold": None, "model": model, "seed": seed, "set": "single", "run": "r1"}
    save_predictions(str(path), PredictionSet(scans, meta))
    return path


def jsonl(proc):
    assert proc.returncode == 0, proc.stderr.decode()
    return [json.loads(line) for line in proc.stdout.decode().splitlines()]


def test_scan_rows_and_file_summary(run_less, tmp_path):
    path = write_preds(tmp_path / "p.npz", [0, 2, 4])
    rows = jsonl(run_less("metrics", path))
    scans, files = [r for r in rows if r["row"] == "scan"], [r for r in rows if r["row"] == "file"]
    assert len(scans) == 3 and len(files) == 1 and not [r for r in rows if r["row"] == "group"]
    assert [r["com_error_mm_3d"] for r in scans] == pytest.approx([0.0, 1.0, 2.0])
    truth = _truth((-2.0, 1.0, -1.0))
    expected = score_labels(np.roll(truth.data, 2, axis=2), truth.data, truth.origin_mm, truth.spacing_mm)
    assert scans[1]["f1_3d"] == pytest.approx(expected["f1_3d"])
    assert scans[0]["model"] == "less" and scans[0]["seed"] == 0 and scans[0]["set"] == "single"
    assert files[0]["n"] == 3 and files[0]["com_error_mm_3d"] == pytest.approx(1.0)
    assert files[0]["com_error_mm_3d_std"] == pytest.approx(1.0) and files[0]["com_error_mm_3d_n"] == 3
    tp = sum(r["tp_3d"] for r in scans)
    fp, fn = sum(r["fp_3d"] for r in scans), sum(r["fn_3d"] for r in scans)
    assert files[0]["f1_micro_3d"] == pytest.approx(2 * tp / (2 * tp + fp + fn))


def test_seeds_aggregate_to_mean_and_std(run_less, tmp_path):
    paths = [write_preds(tmp_path / f"s{seed}.npz", shifts, seed=seed)
             for seed, shifts in enumerate([[0, 1], [1, 2], [2, 4]])]
    rows = jsonl(run_less("metrics", *paths, "--summary-only"))
    assert {r["row"] for r in rows} == {"file", "group"}
    files = [r for r in rows if r["row"] == "file"]
    (group,) = [r for r in rows if r["row"] == "group"]
    per_file = [f["com_error_mm_3d"] for f in files]
    assert per_file == pytest.approx([0.25, 0.75, 1.5])
    assert group["n"] == 3 and group["com_error_mm_3d_n"] == 3 and group["model"] == "less"
    assert group["com_error_mm_3d"] == pytest.approx(np.mean(per_file))
    assert group["com_error_mm_3d_std"] == pytest.approx(np.std(per_file, ddof=1))
    by_seed = jsonl(run_less("metrics", *paths, "--summary-only", "--group-by", "seed"))
    assert [r["seed"] for r in by_seed if r["row"] == "group"] == [0, 1, 2]
    by_insert = jsonl(run_less("metrics", *paths, "--summary-only", "--group-by", "insert,model"))
    groups = [r for r in by_insert if r["row"] == "group"]
    assert [(g["insert"], g["n"]) for g in groups] == [("St10C5", 3), ("St11C5", 3)]
    by_meta = jsonl(run_less("metrics", *paths, "--summary-only", "--group-by", "run"))
    assert [(g["run"], g["n"]) for g in by_meta if g["row"] == "group"] == [("r1", 3)]


@pytest.mark.parametrize("fmt, marker", [("table", "±"), ("markdown", "|---")])
def test_human_formats(run_less, tmp_path, fmt, marker):
    paths = [write_preds(tmp_path / f"s{i}.npz", [i, 1], seed=i) for i in range(2)]
    proc = run_less("metrics", *paths, "--format", fmt)
    assert proc.returncode == 0, proc.stderr.decode()
    out = proc.stdout.decode()
    assert marker in out and "com_error_mm_3d" in out and "(n=2)" in out


def test_threshold_relabels_from_probabilities(run_less, tmp_path):
    path = write_preds(tmp_path / "p.npz", [0], probs_scale=0.6)  # inclusion probability 0.6 where predicted
    (scan, _) = jsonl(run_less("metrics", path))
    assert scan["f1_3d"] == 1.0 and scan["threshold"] is None
    (scan, _) = jsonl(run_less("metrics", path, "--threshold", "0.8"))
    assert scan["pred_empty_3d"] is True and scan["recall_3d"] == 0.0 and scan["precision_3d"] is None
    assert scan["com_error_mm_3d"] is None and scan["threshold"] == 0.8


def test_pillar_class_on_request(run_less, tmp_path):
    path = write_preds(tmp_path / "p.npz", [1])
    (scan, _) = jsonl(run_less("metrics", path, "--cls", "pillar"))
    assert scan["cls"] == "pillar" and scan["f1_3d"] is None and scan["truth_empty_3d"] is True


def test_average_baseline_rows(run_less, tmp_path):
    train = tmp_path / "train.npz"
    save_scans(str(train), random_scanset(n_scans=2))
    paths = [write_preds(tmp_path / f"s{i}.npz", [0, 1], seed=i) for i in range(2)]
    rows = jsonl(run_less("metrics", *paths, "--baseline-from", train))
    base = [r for r in rows if r["row"] == "scan" and r["model"] == "average"]
    assert len(base) == 2  # once per distinct test set, not once per seed
    assert all(r["diameter_error_mm_3d"] is not None and r["com_error_mm_3d"] > 0 for r in base)
    assert {r["model"] for r in rows if r["row"] == "group"} == {"less", "average"}
    by_insert = jsonl(run_less("metrics", *paths, "--baseline-from", train, "--group-by", "insert",
                               "--summary-only"))
    groups = [(g["model"], g["insert"], g["n"]) for g in by_insert if g["row"] == "group"]
    assert groups == [("less", "St10C5", 2), ("less", "St11C5", 2), ("average", "St10C5", 1),
                      ("average", "St11C5", 1)]


def test_several_models_make_one_table_with_the_baseline(run_less, tmp_path):
    train = tmp_path / "train.npz"
    save_scans(str(train), random_scanset(n_scans=2))
    paths = [write_preds(tmp_path / f"{m}.npz", shifts, model=m) for m,
             shifts in (("less", [0, 1]), ("fm", [2, 2]))]
    args = ("metrics", *paths, "--baseline-from", train, "--group-by", "model", "--summary-only")
    files = [r for r in jsonl(run_less(*args)) if r["row"] == "file"]
    assert [(r["model"], r["n"]) for r in files] == [("less", 2), ("fm", 2), ("average", 2)]
    assert [r["com_error_mm_3d"] for r in files[:2]] == pytest.approx([0.25, 1.0])
    proc = run_less(*args, "--format", "table")
    assert proc.returncode == 0, proc.stderr.decode()
    lines = proc.stdout.decode().splitlines()                       # header, rule, one row per model
    assert len(lines) == 5 and [line.split()[1] for line in lines[2:]] == ["less", "fm", "average"]
    # groups pooling files stay
    seeds = [write_preds(tmp_path / f"s{i}.npz", [0, 1], seed=i) for i in range(2)]
    out = run_less("metrics", *seeds, "--group-by", "model", "--summary-only", "--format",
                   "table").stdout.decode()
    assert len(out.split("\n\n")) == 2 and "(n=2)" in out


def test_prediction_file_from_stdin(run_less, tmp_path):
    path = write_preds(tmp_path / "p.npz", [0, 2])
    rows = jsonl(run_less("metrics", "-", input=path.read_bytes()))
    assert [r["com_error_mm_3d"] for r in rows if r["row"] == "scan"] == pytest.approx([0.0, 1.0])


def test_nifti_pair(run_less, tmp_path):
    truth = _truth((-2.0, 0.0, 0.0))
    pred = LabelVolume(np.roll(truth.data, 2, axis=1), truth.origin_mm, truth.spacing_mm)
    save_nifti(str(tmp_path / "ref.nii.gz"), truth)
    save_nifti(str(tmp_path / "seg.nii.gz"), pred)
    (row, file_row) = jsonl(run_less("metrics", "--truth", "ref.nii.gz", "--pred", "seg.nii.gz"))
    assert row["com_error_mm_3d"] == pytest.approx(2 * SPACING[1]) and row["truth"] == "ref.nii.gz"
    assert file_row["row"] == "file" and file_row["file"] == "seg.nii.gz"


def test_nifti_grids_must_match(run_less, tmp_path):
    truth = _truth((-2.0, 0.0, 0.0))
    save_nifti(str(tmp_path / "ref.nii.gz"), truth)
    save_nifti(str(tmp_path / "moved.nii.gz"),
               LabelVolume(truth.data, truth.origin_mm + 1.0, truth.spacing_mm))
    save_nifti(str(tmp_path / "small.nii.gz"), LabelVolume(truth.data[:3], truth.origin_mm, truth.spacing_mm))
    for name, words in (("moved.nii.gz", "origin"), ("small.nii.gz", "grid")):
        proc = run_less("metrics", "--truth", "ref.nii.gz", "--pred", name)
        err = proc.stderr.decode().strip()
        assert proc.returncode == 1 and proc.stdout == b"" and len(err.splitlines()) == 1
        assert name in err and words in err and "ref.nii.gz" in err


def _no_truth_file(path):
    probs = _onehot(np.full(SHAPE, INCLUSION))
    save_predictions(str(path), PredictionSet([ScanPrediction(probs, np.zeros(3), np.ones(3))], {"dim": 3}))
    return path


@pytest.mark.parametrize("make, words", [
    (lambda p: p, "no such file"),
    (lambda p: (p.write_bytes(b"not a zip"), p)[1], "p.npz"),
    (_no_truth_file, "no scan has a stored truth"),
])
def test_bad_input_is_one_line_and_exit_1(run_less, tmp_path, make, words):
    path = make(tmp_path / "p.npz")
    proc = run_less("metrics", path)
    err = proc.stderr.decode().strip()
    assert proc.returncode == 1 and proc.stdout == b"", err
    assert len(err.splitlines()) == 1 and words in err


@pytest.mark.parametrize("with_file, args, words", [
    (True, ["--group-by", "sed"], "did you mean 'seed'"),
    (False, ["--truth", "ref.nii.gz"], "--truth and --pred"),
    (False, [], "give prediction files"),
    (False, ["--truth", "a.nii.gz", "--pred", "b.nii.gz", "--threshold", "0.5"], "--threshold needs"),
])
def test_usage_errors_exit_2(run_less, tmp_path, with_file, args, words):
    files = [write_preds(tmp_path / "p.npz", [0])] if with_file else []
    proc = run_less("metrics", *files, *args)
    assert proc.returncode == 2 and proc.stdout == b""
    assert words in proc.stderr.decode()


def test_bench_metrics_quick(run_less):
    rows = jsonl(run_less("bench", "metrics", "--quick", "--repeats", "1"))
    assert [r["case"].split(":")[0] for r in rows][1] == "baseline"
    assert rows[0]["ratio_vs_f1_only"] > 0 and rows[3]["diameters_agree"] is True
    assert rows[0]["diameter_true_mm_3d"] == pytest.approx(rows[2]["diameter_mm"])


def test_show_picks_the_tables_metrics_in_order(run_less, tmp_path):
    paths = [write_preds(tmp_path / f"s{i}.npz", [i, 1], seed=i) for i in range(2)]
    show = ("--show", "diameter_error_mm_3d,f1_micro_3d", "--show", "com_error_mm_3d")
    lines = run_less("metrics", *paths, "--summary-only", *show, check=True).stdout.decode().splitlines()
    assert lines[0].split() == ["file", "model", "n", "diameter_error_mm_3d", "f1_micro_3d",
                                "com_error_mm_3d"]
    scans = run_less("metrics", paths[0], "--show", "f1_micro_3d,f1_2d", check=True).stdout.decode()
    # scan rows: no micro F1
    assert scans.splitlines()[0].split()[-1] == "f1_2d" and "com_error_mm_3d" not in scans
    md = run_less("metrics", paths[0], "--summary-only", "--show", "f1_3d", "--format", "markdown",
                  check=True)
    assert md.stdout.decode().splitlines()[0].split("|")[-2].strip() == "f1_3d"
    typo = run_less("metrics", paths[0], "--show", "com_error_3d")
    assert typo.returncode == 2 and b"did you mean 'com_error_mm_3d'" in typo.stderr and not typo.stdout
    as_json = run_less("metrics", paths[0], "--show", "f1_3d", "--format", "jsonl")
    assert as_json.returncode == 2 and b"keeps every metric" in as_json.stderr


def _prefix_file(path, record_scans: bool):
    """Two scans imaged at 3 prefixes each (image predict --steps 3): early prefixes far off (shifted 6
    voxels), the whole scan 1 voxel off; ``record_scans`` stores which scan each image is."""
    images = []
    for s in range(2):
        truth = _truth((-2.0, 1.0 * s, -1.0))
        for steps, shift in ((4, 6), (8, 6), (12, 1)):
            images.append(ScanPrediction(probs=_onehot(np.roll(truth.data, shift, axis=2)),
                                         origin_mm=truth.origin_mm, spacing_mm=truth.spacing_mm,
                                         truth=truth.data, insert=f"St1{s}C5", orientation=0, steps=steps,
                                         scan=s if record_scans else -1))
    save_predictions(str(path), PredictionSet(images, {"dim": 3, "model": "less"}))
    return path


@pytest.mark.parametrize("record_scans", [True, False], ids=["recorded", "told by order"])
def test_a_steps_file_is_scored_on_whole_scans_not_on_each_prefix(run_less, tmp_path, record_scans):
    _prefix_file(tmp_path / "steps.npz", record_scans)
    whole = write_preds(tmp_path / "whole.npz", [1, 1])
    proc = run_less("metrics", "steps.npz", "--format", "jsonl")
    assert proc.returncode == 0, proc.stderr.decode()
    rows = jsonl(proc)
    scans = [r for r in rows if r["row"] == "scan"]
    assert [(r["scan"], r["steps"]) for r in scans] == [(0, 12), (1, 12)]
    summary = next(r for r in rows if r["row"] == "file")
    expected = next(r for r in jsonl(run_less("metrics", whole.name, "--format", "jsonl"))
                    if r["row"] == "file")
    assert summary["f1_3d_n"] == 2 and summary["f1_micro_3d"] == pytest.approx(expected["f1_micro_3d"])
    assert ("steps.npz: 6 images of 2 scans (prefixes from image predict --steps/--every); each scan is "
            "scored once, on its whole sequence") in proc.stderr.decode()


def test_image_predict_steps_then_metrics_counts_the_scans(run_less, tmp_path):
    from imaging_factory import save_tiny_imager

    save_tiny_imager(str(tmp_path / "im.pt"))
    save_scans(str(tmp_path / "s.npz"), random_scanset(n_scans=2, traj_per_scan=2, max_len=8, seed=3))
    assert run_less("image", "predict", "im.pt", "s.npz", "-o", "p.npz", "--steps", "3").returncode == 0
    proc = run_less("metrics", "p.npz", "--format", "jsonl")
    assert proc.returncode == 0, proc.stderr.decode()
    assert [r["scan"] for r in jsonl(proc) if r["row"] == "scan"] == [0, 1]
    info = json.loads(run_less("info", "p.npz", "--format", "jsonl").stdout)
    assert (info["scans"], info["images"]) == (2, 6)
