"""``less info`` on each of the toolkit's files: scan sets (tests/cli/test_dataset_commands.py), prediction
files, checkpoints and label volumes, each record checked against counts made here from the file's own
arrays; and one clear line for a file that is none of them."""

import json

import numpy as np
import pytest
import torch
from factories import random_scanset, sphere_labels
from imaging_factory import make_representation, save_tiny_imager

from lesscli.io.labels import load_nifti_labels, save_nifti
from lesscli.io.predictions import PredictionSet, ScanPrediction, save_predictions
from lesscli.io.scans import save_scans


def info(run_less, *args):
    proc = run_less("info", *args, "--format", "jsonl", check=True)
    (record,) = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    return record


def test_label_volume(run_less, tmp_path):
    volume = sphere_labels(radius_mm=7.0, shape=(9, 20, 24), spacing=(1.5, 0.8, 0.6))
    save_nifti(str(tmp_path / "truth.nii.gz"), volume)
    record = info(run_less, "truth.nii.gz")
    data = load_nifti_labels(str(tmp_path / "truth.nii.gz")).data
    assert record["kind"] == "label volume" and record["shape"] == [9, 20, 24]
    assert record["spacing_mm"] == pytest.approx([1.5, 0.8, 0.6])           # NIfTI keeps float32 voxel sizes
    expected = {name: int((data == code).sum()) for code, name in enumerate(("background", "insert", "pillar",
                                                                            "inclusion"))}
    assert record["class_voxels"] == expected and expected["inclusion"] > 0 and expected["pillar"] == 0
    assert record["class_volume_mm3"]["inclusion"] == pytest.approx(expected["inclusion"] * 1.5 * 0.8 * 0.6)


def test_prediction_file(run_less, tmp_path):
    rng = np.random.default_rng(3)
    scans = []
    for i, shape in enumerate([(2, 5, 6), (2, 5, 6), (3, 4, 4)]):
        logits = rng.normal(size=(4, *shape))
        probs = (np.exp(logits) / np.exp(logits).sum(0)).astype(np.float32)
        scans.append(ScanPrediction(probs, np.zeros(3), np.array([1.0, 0.5, 0.5]), insert=f"St1{i}C5",
                                    orientation=2 * i, steps=10 * (i + 1),
                                    truth=None if i == 2 else np.ones(shape, np.uint8)))
    save_predictions(str(tmp_path / "p.npz"), PredictionSet(scans, {"dim": 3, "model": "toy", "seed": 4}))
    record = info(run_less, "p.npz")
    assert record["kind"] == "prediction set" and record["schema"] == "less.pred/1"
    assert (record["scans"], record["with_truth"]) == (3, 2)
    assert record["inserts"] == ["St10C5", "St11C5", "St12C5"] and record["orientations"] == [0, 2, 4]
    assert record["grid_shapes"] == [[2, 5, 6], [3, 4, 4]] and record["classes"] == [4]
    assert record["steps"] == {"min": 10.0, "mean": 20.0, "max": 30.0}
    argmax = np.concatenate([p.probs.argmax(0).ravel() for p in scans])      # no threshold: argmax labels
    assert list(record["class_voxels"].values()) == np.bincount(argmax, minlength=4).tolist()
    assert (record["meta"] == {"dim": 3, "model": "toy", "seed": 4}
            and 0 < record["entropy_mean_nats"] < np.log(4))


def test_checkpoints_of_each_kind(run_less, tmp_path):
    save_tiny_imager(str(tmp_path / "imager.pt"), dim=3)
    scans = random_scanset(n_scans=3)
    make_representation(str(tmp_path / "rep.pt"), scans)
    save_scans(str(tmp_path / "s.npz"), scans)
    run_less("image", "fit", "s.npz", "--model", "forcemap", "-o", "fm.pt", check=True)
    imager, rep, classical = (info(run_less, f) for f in ("imager.pt", "rep.pt", "fm.pt"))
    state = torch.load(tmp_path / "imager.pt", weights_only=True)["model_state"]
    assert imager["kind"] == "imager" and imager["decoder"] == "patch" and imager["model"] == "less"
    assert imager["parameters"] == sum(v.numel() for v in state.values()) > 0
    assert imager["grid"]["shape"] == [3, 48, 48] and imager["epochs"] == 0 and imager["force_units"] == "N"
    # argmax: none chosen
    assert imager["labelling"] is None and imager["image"] == {"dim": 3, "slice": -1}
    assert rep["kind"] == "representation" and rep["model"] == "less" and rep["grid"] is None
    assert classical["kind"] == "classical imager" and classical["parameters"] == 0
    assert "threshold" in classical["settings"] and "prior" not in classical["settings"]
    assert classical["history"][0]["command"].startswith("less image fit s.npz --model forcemap")


def test_a_file_of_no_kind_is_one_clear_line(run_less, tmp_path):
    for name, text in (("notes.pt", b"not a checkpoint"), ("scan.nii.gz", b"not a volume"),
                       ("data.npz", b"not an archive")):
        (tmp_path / name).write_bytes(text)
        proc = run_less("info", name)
        lines = proc.stderr.decode().strip().splitlines()
        assert proc.returncode == 1 and not proc.stdout and len(lines) == 1 and name in lines[0], lines


def test_a_prediction_file_on_stdin_is_told_by_its_schema(run_less, tmp_path):
    probs = np.full((4, 2, 3, 3), 0.25, np.float32)
    save_predictions(str(tmp_path / "p.npz"),
                     PredictionSet([ScanPrediction(probs, np.zeros(3), np.ones(3))], {}))
    piped = run_less("info", "-", "--format", "jsonl", input=(tmp_path / "p.npz").read_bytes(), check=True)
    assert json.loads(piped.stdout) == info(run_less, "p.npz")
    assert json.loads(piped.stdout)["kind"] == "prediction set"


def test_several_files_name_themselves_and_all_are_read_first(run_less, tmp_path):
    save_nifti(str(tmp_path / "truth.nii.gz"), sphere_labels(shape=(6, 12, 12)))
    save_scans(str(tmp_path / "s.npz"), random_scanset())
    proc = run_less("info", "truth.nii.gz", "s.npz", "--format", "jsonl", check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [(r["file"], r["kind"]) for r in rows] == [("truth.nii.gz", "label volume"), ("s.npz", "scan set")]
    # one file: no name
    assert {k: v for k, v in rows[1].items() if k != "file"} == info(run_less, "s.npz")
    tables = run_less("info", "truth.nii.gz", "s.npz", "--format", "table", check=True).stdout.decode()
    assert ([t.splitlines()[2].split() for t in tables.split("\n\n")]
            == [["file", "truth.nii.gz"], ["file", "s.npz"]])
    missing = run_less("info", "s.npz", "gone.npz")
    assert missing.returncode == 1 and not missing.stdout and b"gone.npz: no such file" in missing.stderr
