"""Pretraining: config, checkpoints, the loop (resume, NaN guard, determinism), SSL learning, CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from factories import REPO, poke_scanset, random_scanset, tiny_cfg

from lesscli.data.batching import ScanDataset, batches, collate, compute_norm_stats
from lesscli.errors import LessError, TrainingError
from lesscli.io.checkpoint import load_checkpoint, save_checkpoint
from lesscli.io.scans import save_scans
from lesscli.train import loop as loop_mod
from lesscli.train import pretrain as pretrain_mod
from lesscli.train.config import LoopConfig, PretrainConfig, load_config
from lesscli.train.pretrain import build_model, pretrain
from lesscli.train.representation import load_representation

torch.set_num_threads(1)



# ------------------------------------------------------------------------------------------- config


def test_config_precedence_file_then_options_then_set(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[model]\ndim = 32\nname = 'global'\n[train]\nlr = 0.01\nepochs = 7\n")
    cfg = load_config(PretrainConfig, str(path), ["train.lr=5e-4", "k_query=4"],
                      {"train.epochs": 3, "model.dim": None})
    assert (cfg.model.dim, cfg.model.name, cfg.train.lr, cfg.train.epochs, cfg.ssl.k_query) == (32, "global",
                                                                                               5e-4, 3, 4)
    assert isinstance(load_config(PretrainConfig, None, ["spacing_mm=5"]).model.spacing_mm, float)


@pytest.mark.parametrize("item,match", [("dimm=3", "did you mean 'dim'"), ("train.lr=fast", "expects float"),
                                        ("modle.dim=3", "did you mean 'model'"), ("lr", "key=value")])
def test_config_errors_are_one_clear_line(item, match):
    with pytest.raises(LessError, match=match):
        load_config(PretrainConfig, None, [item])


# -------------------------------------------------------------------------------------- checkpoints


def test_checkpoint_loads_with_weights_only_and_rebuilds_the_encoder(tmp_path):
    train = random_scanset(n_scans=2, seed=1)
    stats = compute_norm_stats(train)
    model = build_model(tiny_cfg(), 90)
    path = str(tmp_path / "rep.pt")
    config = {"encoder": model.encoder.config()}
    save_checkpoint(path, model.state_dict(), config, stats, [{"command": "test"}])
    raw = torch.load(path, weights_only=True)
    assert raw["norm_stats"]["force_mean"] == stats["force_mean"] and raw["history"] == [{"command": "test"}]
    encoder, ckpt = load_representation(path)
    batch = batches(train, ckpt["norm_stats"])[0]
    with torch.no_grad():
        torch.testing.assert_close(encoder(batch).z, model.encoder.eval()(batch).z, atol=0, rtol=0)
    grown = encoder.with_grid(96.0)
    assert grown.n_particles > encoder.n_particles


def test_bad_checkpoint_files_raise_data_errors(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(LessError, match="bad.pt"):
        load_checkpoint(str(bad))
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(2)}, other)
    with pytest.raises(LessError, match="not a less checkpoint"):
        load_representation(str(other))


def test_norm_stats_come_from_training_data_only():
    train, other = random_scanset(n_scans=2, seed=1), random_scanset(n_scans=2, seed=2)
    stats = compute_norm_stats(train)
    flat = train.force.reshape(train.n_steps, -1)
    np.testing.assert_allclose(stats["force_mean"], flat.mean(0), rtol=1e-5, atol=1e-7)
    item = ScanDataset(other, stats)[0]
    lo, hi = other.scan_step_offsets()[:2]
    expected = (other.force[lo:hi].reshape(hi - lo, -1) - np.array(stats["force_mean"])) / np.array(
        stats["force_std"])
    np.testing.assert_allclose(item["force"].numpy(), expected, rtol=1e-5, atol=1e-5)
    assert len(set(stats["force_std"])) == 1 and stats["mode"] == "global"
    np.testing.assert_allclose(stats["force_std"][0], np.sqrt(flat.astype(np.float64).var(0).mean()),
                               rtol=1e-6)
    per_feature = compute_norm_stats(train, "feature")
    np.testing.assert_allclose(per_feature["force_std"], flat.astype(np.float64).std(0), rtol=1e-6)
    with pytest.raises(LessError, match="unknown"):
        compute_norm_stats(train, "per-taxel")
    with pytest.raises(LessError, match="features"):
        ScanDataset(other, {"force_mean": [0.0] * 6, "force_std": [1.0] * 6})


# ---------------------------------------------------------------------------------------------- loop


def test_fixed_seed_gives_identical_checkpoints(tmp_path):
    train, val = poke_scanset(3, seed=1, traj_per_scan=4), poke_scanset(2, seed=2, traj_per_scan=4)
    paths = [str(tmp_path / f"r{i}.pt") for i in range(3)]
    for path, seed in zip(paths, [5, 5, 6]):
        pretrain(train, val, tiny_cfg(seed=seed), path)
    states = [load_checkpoint(p)["model_state"] for p in paths]
    assert all(torch.equal(states[0][k], states[1][k]) for k in states[0])
    assert not all(torch.equal(states[0][k], states[2][k]) for k in states[0])
    logs = (tmp_path / "r0.log.jsonl").read_text().splitlines()
    assert [json.loads(ln)["epoch"] for ln in logs] == [1, 2]


def test_resume_after_interruption_continues_exactly(tmp_path, monkeypatch):
    train = poke_scanset(3, seed=1, traj_per_scan=4)          # 2 batches per epoch
    straight, split = str(tmp_path / "a.pt"), str(tmp_path / "b.pt")
    pretrain(train, None, tiny_cfg(epochs=3), straight)
    calls = {"n": 0}
    real = pretrain_mod.ssl_loss_fn

    def interrupted(model, batch, gen):
        calls["n"] += 1
        if calls["n"] == 4:
            raise KeyboardInterrupt
        return real(model, batch, gen)

    monkeypatch.setattr(pretrain_mod, "ssl_loss_fn", interrupted)
    with pytest.raises(KeyboardInterrupt):
        pretrain(train, None, tiny_cfg(epochs=3), split)
    monkeypatch.setattr(pretrain_mod, "ssl_loss_fn", real)
    summary = pretrain(train, None, tiny_cfg(epochs=3), split, resume=True)
    for a, b in [(straight, split), (straight[:-3] + ".last.pt", split[:-3] + ".last.pt")]:
        sa, sb = load_checkpoint(a)["model_state"], load_checkpoint(b)["model_state"]
        assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert [h["epoch"] for h in load_checkpoint(split)["history"] if "epoch" in h] == [1, 2, 3]
    assert summary["epochs"] == 3
    with pytest.raises(TrainingError, match="nothing to resume"):
        pretrain(train, None, tiny_cfg(), str(tmp_path / "c.pt"), resume=True)


def test_non_finite_loss_stops_naming_the_step_and_keeps_last_good_checkpoint(tmp_path):
    train = poke_scanset(4, seed=1, traj_per_scan=3)
    stats = compute_norm_stats(train)
    model = build_model(tiny_cfg(), 90)
    calls = {"n": 0}

    def loss_fn(m, batch, gen):
        calls["n"] += 1
        loss = m(batch, gen)
        return loss * math.nan if calls["n"] == 4 else loss

    path = str(tmp_path / "rep.pt")
    with pytest.raises(TrainingError, match=r"epoch 2, batch 2 \(global step 4\).*kept at .*rep.pt"):
        loop_mod.fit(model, loss_fn, ScanDataset(train, stats), None, LoopConfig(epochs=3, batch_size=2),
                     collate_fn=collate, output=path, config={"encoder": model.encoder.config()},
                     norm_stats=stats)
    ckpt = load_checkpoint(path)
    assert [h["epoch"] for h in ckpt["history"]] == [1]
    assert all(torch.isfinite(v).all() for v in ckpt["model_state"].values())


def test_non_finite_validation_loss_stops_too(tmp_path):
    train = poke_scanset(2, seed=1, traj_per_scan=3)
    stats = compute_norm_stats(train)
    model = build_model(tiny_cfg(), 90)

    def loss_fn(m, batch, gen):
        loss = m(batch, gen)
        return loss if m.training else loss * math.inf

    with pytest.raises(TrainingError, match="non-finite validation loss .* epoch 1"):
        loop_mod.fit(model, loss_fn, ScanDataset(train, stats), ScanDataset(train, stats),
                     LoopConfig(epochs=2), collate_fn=collate, output=str(tmp_path / "rep.pt"), config={},
                     norm_stats=stats)
    assert not (tmp_path / "rep.pt").exists()


def ssl_cfg(name: str, epochs: int, batch_size: int) -> PretrainConfig:
    cfg = tiny_cfg(epochs=epochs, batch_size=batch_size, lr=1e-2)
    cfg.model.name, cfg.model.dim, cfg.ssl.k_input, cfg.ssl.k_query = name, 32, 8, 8
    return cfg


def test_ssl_on_simulated_pokes_beats_predict_the_mean(tmp_path):
    """Tiny simulated single-inclusion poke set (demo scene, 2 inserts x 2 orientations, 16 pokes,
    1:50 subsampling): LESS's validation force MSE well below predicting the training mean."""
    from lesscli.sim.scene import load_scene
    from lesscli.sim.simulate import simulate

    scene = load_scene(str(REPO / "examples" / "scenes" / "demo.toml"),
                       ["motion.n_traj=16", "labels.shape=[4,8,8]", "phantoms.orientations=[0,4]"])
    scans = simulate(scene)
    keep = np.zeros(scans.n_steps, bool)
    for lo, hi in zip(scans.traj_offsets[:-1], scans.traj_offsets[1:]):
        keep[lo:hi:50] = True
    scans = scans.select_steps(keep)
    assert list(scans.scan_insert) == ["St16C9", "St16C9", "St12D13", "St12D13"]
    summary = pretrain(scans.select_scans([0, 1, 3]), scans.select_scans([2]), ssl_cfg("less", 25, 1),
                       str(tmp_path / "rep.pt"))
    assert summary["val_baseline_mse"] > 0.5
    assert summary["val_mse"] < 0.5 * summary["val_baseline_mse"], summary


def test_global_ssl_training_beats_predict_the_mean(tmp_path):
    """GLOBAL on learnable synthetic pokes: validation force MSE well below predicting the mean."""
    summary = pretrain(poke_scanset(6, seed=3), poke_scanset(3, seed=4), ssl_cfg("global", 30, 2),
                       str(tmp_path / "rep.pt"))
    assert summary["val_baseline_mse"] > 0.5
    assert summary["val_mse"] < 0.5 * summary["val_baseline_mse"], summary


# ----------------------------------------------------------------------------------------------- CLI


def test_cli_pretrain_writes_checkpoint_log_and_summary(run_less, tmp_path):
    save_scans(str(tmp_path / "tr.npz"), poke_scanset(3, seed=1, traj_per_scan=4))
    save_scans(str(tmp_path / "va.npz"), poke_scanset(2, seed=2, traj_per_scan=4))
    proc = run_less("pretrain", "tr.npz", "--val", "va.npz", "-o", "rep.pt", "--epochs", "2", "--dim", "8",
                    "--spacing-mm", "10", "--set", "n_freq=2", "--device", "cpu", "--format", "jsonl",
                    check=True, env={"OMP_NUM_THREADS": "1"})
    summary = json.loads(proc.stdout)
    assert summary["selected_by"] == "val_loss" and summary["val_baseline_mse"] > 0
    ckpt = torch.load(str(tmp_path / "rep.pt"), weights_only=True)
    assert ckpt["config"]["model"]["dim"] == 8 and ckpt["config"]["model"]["n_freq"] == 2
    assert ckpt["history"][0]["command"].startswith("less pretrain")
    assert len((tmp_path / "rep.log.jsonl").read_text().splitlines()) == 2


# option values:
@pytest.mark.parametrize("args,match,code", [(["--model", "globl"], "did you mean 'global'", 2),
                                             # usage errors
                                             (["--set", "epochs=0"], "train.epochs", 2),
                                             # data: exit 1
                                             (["--val", "missing.npz"], "missing.npz", 1)])
def test_cli_pretrain_errors_leave_no_output(tmp_path, monkeypatch, capsys, args, match, code):
    from lesscli.cli.main import main

    monkeypatch.chdir(tmp_path)
    save_scans("tr.npz", random_scanset(n_scans=2, seed=1))
    with pytest.raises(SystemExit) as exit_info:
        main(["pretrain", "tr.npz", "-o", "rep.pt", "--device", "cpu", *args])
    err = capsys.readouterr().err
    assert exit_info.value.code == code and match in err and "Traceback" not in err
    last = err.strip().splitlines()[-1]                          # the one error line (after usage, hint)
    assert last.startswith("less: error: " if code == 1 else "Error: Invalid value for ")
    assert code == 2 or len(err.strip().splitlines()) == 1
    assert not (tmp_path / "rep.pt").exists()
