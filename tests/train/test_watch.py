"""Watching training: the epoch bar, TensorBoard scalars (or one clear error without the package), ``plot
log``."""

import json
import sys

import numpy as np
import pytest
from factories import poke_scanset
from imaging_factory import learnable_scanset, make_representation

from lesscli.io.scans import save_scans
from lesscli.train.watch import bar_postfix

ONE_THREAD = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
TINY = ["--dim", "8", "--spacing-mm", "10", "--set", "n_freq=2", "--device", "cpu", "--format", "jsonl"]


def _scalar_tags(folder):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(folder))
    acc.Reload()
    return {tag: [e.value for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


def _colour_share(png, hex_colour):
    import matplotlib.image

    rgb = matplotlib.image.imread(str(png))[..., :3]
    target = np.array([int(hex_colour[i:i + 2], 16) / 255 for i in (1, 3, 5)])
    return float((np.abs(rgb - target).max(axis=-1) < 0.02).mean())


def test_bar_postfix_shows_loss_and_the_best_validation_value():
    rec = {"train_loss": 0.51234, "val_loss": 0.4}
    assert bar_postfix(rec, {"train_loss": 1, "val_loss": 0.3}) == {"loss": "0.5123", "best_val_loss": "0.3"}
    assert bar_postfix(rec, {"train_loss": 1, "val_loss": 0.3, "val_score": 0.5})["best_val_f1"] == "0.500"
    assert bar_postfix(rec, {"train_loss": 0.25, "val_loss": None}) == {"loss": "0.5123", "best_loss": "0.25"}


def test_two_pretrain_seeds_watched_in_tensorboard_and_plotted(run_less, tmp_path):
    pytest.importorskip("tensorboard")
    save_scans(str(tmp_path / "tr.npz"), poke_scanset(3, seed=1, traj_per_scan=4))
    save_scans(str(tmp_path / "va.npz"), poke_scanset(2, seed=2, traj_per_scan=4))
    for seed in (0, 1):
        proc = run_less("-v", "pretrain", "tr.npz", "--val", "va.npz", "-o", f"rep_s{seed}.pt", "--epochs",
                        "3", "--seed", seed, "--tensorboard", f"tb/s{seed}", *TINY, check=True,
                        env=ONE_THREAD)
        err = proc.stderr.decode()
        # the epoch line (a log)
        assert "less: train: epoch 3/3, " in err and "best_val_loss=" in err
        assert "less: epoch 3/3: 2/2 steps (100 %)" in err                               # -v: batches too
        log = [json.loads(line) for line in (tmp_path / f"rep_s{seed}.log.jsonl").read_text().splitlines()]
        summary = json.loads(proc.stdout)
        assert all(r["val_baseline_mse"] == pytest.approx(summary["val_baseline_mse"]) for r in log)
        tags = _scalar_tags(tmp_path / "tb" / f"s{seed}")
        assert tags["train_loss"] == pytest.approx([r["train_loss"] for r in log])
        assert tags["val_loss"] == pytest.approx([r["val_loss"] for r in log]) and "val_baseline_mse" in tags
    proc = run_less("plot", "log", "rep_s0.log.jsonl", "rep_s1.log.jsonl", "-o", "curves.png", "--format",
                    "jsonl", check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [r["run"] for r in rows] == ["rep_s0", "rep_s1"] and all(0 < r["best_force_ratio"] for r in rows)
    assert _colour_share(tmp_path / "curves.png", "#1f77b4") > 1e-4      # run 1 drawn (C0)
    assert _colour_share(tmp_path / "curves.png", "#ff7f0e") > 1e-4      # run 2 drawn (C1)


def test_image_fit_logs_f1_per_epoch_to_tensorboard_and_plot(run_less, tmp_path):
    pytest.importorskip("tensorboard")
    train = learnable_scanset(4, 10)
    save_scans(str(tmp_path / "train.npz"), train)
    save_scans(str(tmp_path / "val.npz"), learnable_scanset(2, 21))
    make_representation(str(tmp_path / "rep.pt"), train, dim=8)
    run_less("image", "fit", "train.npz", "--val", "val.npz", "--rep", "rep.pt", "-o", "img.pt", "--dim", "2",
             "--epochs", "2", "--device", "cpu", "--set", "image.width=8", "--set", "image.patch_px=8",
             "--tensorboard", "tb", check=True, env=ONE_THREAD)
    log = [json.loads(line) for line in (tmp_path / "img.log.jsonl").read_text().splitlines()]
    assert _scalar_tags(tmp_path / "tb")["val_score"] == pytest.approx([r["val_score"] for r in log])
    proc = run_less("plot", "log", "img.log.jsonl", "-o", "f1.png", "--label", "imager", check=True)
    assert json.loads(proc.stdout)["best_val_f1"] == pytest.approx(max(r["val_score"] for r in log))


@pytest.mark.parametrize("command", [["pretrain", "tr.npz"], ["image", "fit", "tr.npz", "--rep", "rep.pt"]])
def test_tensorboard_missing_is_one_line_before_training(tmp_path, monkeypatch, capsys, command):
    from lesscli.cli.main import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setitem(sys.modules, "tensorboard", None)       # as if the package were not installed
    with pytest.raises(SystemExit) as exit_info:
        main([*command, "-o", "out.pt", "--device", "cpu", "--tensorboard", "tb"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 1 and len(err) == 1
    assert ("--tensorboard tb: the 'tensorboard' package is not installed" in err[0]
            and "less-tactile[tensorboard]" in err[0])
    assert not list(tmp_path.iterdir())                          # nothing loaded (tr.npz does not even exist)


def test_plot_log_bad_input_is_one_line_and_no_png(run_less, tmp_path):
    (tmp_path / "not_a_log.jsonl").write_text('{"f1": 0.5}\n')
    proc = run_less("plot", "log", "not_a_log.jsonl", "-o", "c.png")
    err = proc.stderr.decode().strip().splitlines()
    assert proc.returncode == 1 and len(err) == 1 and "not_a_log.jsonl: not a training log" in err[0]
    (tmp_path / "a.log.jsonl").write_text('{"epoch": 1, "train_loss": 1.0}\n')
    proc = run_less("plot", "log", "a.log.jsonl", "-o", "c.png", "--label", "x", "--label", "y")
    assert proc.returncode == 1 and "2 labels for 1 logs" in proc.stderr.decode()
    assert not (tmp_path / "c.png").exists()
