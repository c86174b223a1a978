"""The tuning search of the headline run (examples/tune.py): every trial scored on validation, best kept."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from conftest import BIN
from factories import example_script

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "examples" / "tune.py"


def _module():
    return example_script("tune")


def _record(trial, scores):
    return {"trial": trial,
            "val": {k: {"f1_micro_3d": f1, "com_error_mm_3d": com} for k, (f1, com) in scores.items()}}


def test_the_best_validation_f1_wins_then_the_smaller_centroid_error():
    tune = _module()
    records = [_record(0, {"1": (0.50, 2.0), "4": (0.61, 3.0)}),
               _record(1, {"1": (0.61, 1.5), "4": (None, None)}),      # a model that predicts nothing
               _record(2, {"1": (0.30, 0.5), "4": (0.31, 0.4)})]
    best, turns = tune.choose(records)
    assert (best["trial"], turns) == (1, 1)
    records[1]["val"]["1"]["com_error_mm_3d"] = 3.5
    best, turns = tune.choose(records)
    assert (best["trial"], turns) == (0, 4)


def test_every_model_runs_the_same_trials_with_its_own_fixed_arguments(tmp_path):
    space = tmp_path / "space.toml"
    space.write_text('[common]\npretrain = ["--batch-size", "2"]\nfit = ["--epochs", "1"]\nturns = [1, 2]\n'
                     '[models.less-taxel]\npretrain = ["--set", "model.map_contrast=plane"]\n'
                     '[[trial]]\npretrain = ["--dim", "8"]\n[[trial]]\npretrain = ["--dim", "16"]\n'
                     'fit = ["--lr", "1e-3"]\n')
    tune = _module()
    plain, taxel = tune.read_space(str(space), "global"), tune.read_space(str(space), "less-taxel")
    assert [t["pretrain"] for t in plain["trials"]] == [["--batch-size", "2", "--dim", "8"],
                                                          ["--batch-size", "2", "--dim", "16"]]
    assert taxel["trials"][1]["pretrain"] == ["--batch-size", "2", "--set", "model.map_contrast=plane",
                                              "--dim", "16"]
    assert taxel["trials"][1]["fit"] == plain["trials"][1]["fit"] == ["--epochs", "1", "--lr", "1e-3"]
    assert plain["turns"] == [1, 2]


@pytest.mark.slow
def test_a_tiny_search_writes_its_log_and_the_chosen_config(tmp_path):
    from imaging_factory import learnable_scanset

    from lesscli.io.scans import save_scans

    save_scans(str(tmp_path / "tr.npz"), learnable_scanset(3, seed=1))
    save_scans(str(tmp_path / "va.npz"), learnable_scanset(2, seed=2))
    space = tmp_path / "space.toml"
    space.write_text('[common]\npretrain = ["--epochs", "1", "--set", "n_freq=2"]\n'
                     'fit = ["--epochs", "1", "--set", "image.patch_px=8", "--set", "image.width=8"]\n'
                     'turns = [1, 2]\n[[trial]]\npretrain = ["--dim", "8"]\n[[trial]]\npretrain = ["--dim", '
                     '"4"]\n[[trial]]\npretrain = ["--dim", "8"]\nfit = ["--lr", "1e-3"]\n')
    cmd = [sys.executable, str(SCRIPT), "run", "--model", "less-taxel", "--space", str(space), "--train",
           "tr.npz", "--val", "va.npz", "--work", "work", "--log", "log.jsonl", "-o", "best.toml", "--less",
           str(BIN / "less")]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, check=False,
                          env={"OMP_NUM_THREADS": "1",
                                                                                  "PATH": str(BIN)})
    assert proc.returncode == 0, proc.stderr
    log = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert [r["trial"] for r in log] == [0, 1, 2] and all(set(r["val"]) == {"1", "2"} for r in log)
    # trial 2 shares trial 0's self-supervision: one representation, trained once, its cost counted in both
    assert sorted(p.name for p in (tmp_path / "work").glob("rep_t?.pt")) == ["rep_t0.pt", "rep_t1.pt"]
    assert all(log[2][k] == log[0][k] for k in ("ssl_best_loss", "ssl_seconds"))
    assert log[2]["train_seconds"] == round(log[2]["ssl_seconds"] + log[2]["fit_seconds"], 1)
    config = tomllib.loads((tmp_path / "best.toml").read_text())
    best, turns = _module().choose(log)
    assert (config["trial"], config["turns"]) == (best["trial"], turns)
    assert config["pretrain"] == log[config["trial"]]["pretrain"]
    printed = subprocess.run([sys.executable, str(SCRIPT), "args", str(tmp_path / "best.toml"), "pretrain"],
                             capture_output=True, text=True, check=True).stdout.split()
    assert printed == config["pretrain"]
    again = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, check=False,
                           env={"OMP_NUM_THREADS": "1",
                                                                                   "PATH": str(BIN)})
    assert again.returncode == 0 and again.stderr == ""            # a rerun reads the log, trains nothing
    # a trial whose fit arguments changed since its record is run again, on the shared representation
    space.write_text(space.read_text().replace('"1e-3"', '"2e-3"'))
    changed = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, check=False,
                             env={"OMP_NUM_THREADS": "1", "PATH": str(BIN)})
    assert changed.returncode == 0, changed.stderr
    reruns = [json.loads(line) for line in changed.stderr.splitlines()]
    assert [r["trial"] for r in reruns] == [2]
