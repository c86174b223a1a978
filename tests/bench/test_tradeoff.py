"""Accuracy-vs-time bench: setting bookkeeping, sharing of trained stages, effects against the seed
spread, prediction arithmetic, the classical imager's knobs, figures, and a tiny run of the command."""

import json
import math

import numpy as np
import pytest

from lesscli.bench import tradeoff
from lesscli.bench.timing import peak_memory
from lesscli.bench.tradeoff import (
    BASES,
    FULL,
    KNOBS,
    QUICK,
    Setting,
    TradeoffRun,
    aggregate,
    compare_to_base,
    effect,
    knobs_for,
    represented,
    run_tradeoff,
    settings_of,
    trained,
)
from lesscli.plots.sweeps import line_figure, noise_figure, pareto_figure, pareto_front

ONE_THREAD = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _png_is_not_blank(path):
    from matplotlib.image import imread

    img = imread(str(path))
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    assert float(img[..., :3].std()) > 0.02


def test_pareto_front_keeps_the_undominated_points_sorted_by_time():
    # (time, score): b dominates c (faster and better); d ties a on time with a lower score
    pts = [(1.0, 0.5), (2.0, 0.8), (3.0, 0.7), (1.0, 0.4), (5.0, 0.9), (float("nan"), 1.0)]
    assert pareto_front(pts) == [0, 1, 4]
    assert pareto_front([(1.0, 0.5), (1.0, 0.5)]) == [0, 1]     # equal points do not dominate each other
    assert pareto_front([]) == []


def test_settings_vary_one_knob_around_the_models_own_base():
    plan = tradeoff.make_plan(False, {"receptive_field": (5.0, 15.0), "dim": (16, 32, 64)})
    found = settings_of(plan, "less-taxel", ["receptive_field", "width"])
    assert [(k, v) for k, v, _ in found] == [("base", ""), ("receptive_field", 5.0),
                                             ("receptive_field", 15.0),
                                              ("width", 8)]
    assert found[0][2] == BASES["less-taxel"] and found[1][2] == Setting(receptive_field_mm=5.0)
    less = settings_of(plan, "less", ["dim"])          # the base's own value is not repeated as a knob row
    assert BASES["less"].dim == 64 and [v for _, v, _ in less] == ["", 16, 32]


def test_every_knob_applies_somewhere_and_both_plans_name_only_known_knobs(run_less):
    assert all(knob.models and set(knob.models) <= set(tradeoff.MODELS) for knob in KNOBS.values())
    for plan in (QUICK, FULL):
        assert set(plan.values) <= set(KNOBS)
    assert set(FULL.values) == set(KNOBS)              # the full plan tries every knob
    assert "receptive_field" in knobs_for("less-taxel") and "receptive_field" not in knobs_for("global")
    assert knobs_for("forcemap") == ["predict_subsample", "threads", "smoothing", "grid", "subsample",
                                     "scans", "pokes"]
    helptext = run_less("bench", "tradeoff", "--help").stdout.decode()
    assert all(knob in helptext for knob in KNOBS)


def test_decoder_knobs_share_the_representation_and_prediction_knobs_the_model():
    base = BASES["less-taxel"]
    assert represented(replace_(base, width=8)) == represented(base) != represented(replace_(base, dim=8))
    assert trained(replace_(base, turns=4, precision="int8", threads=1, predict_every=100)) == base
    assert trained(replace_(base, width=8)) != base


def replace_(s, **kw):
    from dataclasses import replace

    return replace(s, **kw)


def test_effect_needs_more_than_twice_the_larger_seed_spread():
    assert effect(0.05, 0.02, 0.01) == "effect"         # 0.05 > 2 * 0.02
    assert effect(0.03, 0.02, 0.01) == "within noise"   # 0.03 <= 2 * 0.02
    assert effect(-0.05, 0.0, 0.03) == "within noise"   # the base's spread counts too
    assert effect(0.001, 0.0, 0.0) == "effect" and effect(0.0, 0.0, 0.0) == "within noise"
    assert effect(None, 0.1, 0.1) is None


def test_aggregate_is_mean_and_sample_spread_over_seeds():
    rows = aggregate([{"f1_single": 0.7, "train_s": 10.0}, {"f1_single": 0.8, "train_s": 14.0},
                      {"f1_single": None, "train_s": 12.0}])
    assert (rows["seeds"] == 3 and rows["f1_single"] == pytest.approx(0.75)
            and rows["train_s"] == pytest.approx(12.0))
    assert rows["f1_single_std"] == pytest.approx(math.sqrt(((0.7 - 0.75) ** 2 + (0.8 - 0.75) ** 2) / 1))
    assert aggregate([{"f1_single": 0.5}])["f1_single_std"] == 0.0


def test_compare_to_base_gives_ratios_deltas_and_effects_per_model():
    rows = [{"model": "m", "knob": "base", "f1_single": 0.8, "f1_single_std": 0.01, "f1_multiple": 0.6,
             "f1_multiple_std": 0.05, "train_s": 100.0, "latency_ms": 20.0},
            {"model": "m", "knob": "dim", "f1_single": 0.7, "f1_single_std": 0.02, "f1_multiple": 0.62,
             "f1_multiple_std": 0.05, "train_s": 50.0, "latency_ms": 30.0}]
    compare_to_base(rows)
    assert (rows[1]["train_s_ratio"] == 0.5 and rows[1]["latency_ms_ratio"] == 1.5
            and rows[0]["train_s_ratio"] == 1)
    assert rows[1]["f1_single_delta"] == pytest.approx(-0.1) and rows[1]["f1_single_effect"] == "effect"
    assert rows[1]["f1_multiple_effect"] == "within noise" and rows[1]["stream_ms_ratio"] is None


def _fake_stages(monkeypatch, calls):
    monkeypatch.setattr(tradeoff, "make_data", lambda plan,
                        workdir: tradeoff.BenchData(None, None, None, None, 1.0))
    monkeypatch.setattr(tradeoff, "setting_scans", lambda data, s: (s, s))
    seed_of = {}

    def stage(kind, s, seed, *args):
        calls.append((kind, s.dim if kind == "pretrain" else s.width, seed))
        seed_of[args[-1]] = seed
        open(args[-1], "w").close()                       # the checkpoint a stage leaves

    monkeypatch.setattr(tradeoff, "_pretrain", lambda *a: stage("pretrain", *a))
    monkeypatch.setattr(tradeoff, "_fit", lambda *a: stage("fit", *a))
    monkeypatch.setattr("lesscli.train.forcemap_fit.fit_forcemap",
                        lambda scans, path, *a, **k: calls.append(("forcemap",)) or open(path, "w").close())

    def fake_eval(model, s, data, run):
        calls.append(("eval", s.turns, s.precision))
        seed = seed_of.get(model["path"], 0)
        if s.precision == "int8":
            raise ValueError("int8 dynamic quantisation runs on the CPU only")
        return {"f1_single": 0.5 + s.width / 1000 + seed / 100, "f1_multiple": 0.4,
                "latency_ms": 2.0 * s.turns}

    monkeypatch.setattr(tradeoff, "evaluate", fake_eval)
    monkeypatch.setattr(tradeoff, "average_reference", lambda data, run, classical: {"f1_single": 0.3})


def test_a_run_trains_each_stage_once_per_seed_and_says_what_it_cannot_run(monkeypatch, tmp_path):
    calls = []
    _fake_stages(monkeypatch, calls)
    plan = tradeoff.make_plan(True, {"width": (8,), "turns": (4,), "precision": ("int8",)}, seeds=2)
    rows = run_tradeoff(plan, "less-taxel", ["width", "turns", "precision"],
                        TradeoffRun(workdir=str(tmp_path)))
    # one per seed
    assert [c for c in calls if c[0] == "pretrain"] == [("pretrain", 16, 0), ("pretrain", 16, 1)]
    assert [c for c in calls if c[0] == "fit"] == [("fit", 16, 0), ("fit", 16, 1), ("fit", 8, 0),
                                                   ("fit", 8, 1)]
    assert [(r["knob"], r["value"]) for r in rows] == [("base", ""), ("width", 8), ("turns", 4),
                                                       ("precision", "int8"), ("reference", "classical"),
                                                       ("reference", "average")]
    base, width, turns, int8 = rows[:4]
    assert base["seeds"] == 2 and base["f1_single"] == pytest.approx(0.516 + 0.005)   # seeds 0 and 1
    assert base["f1_single_std"] == pytest.approx(0.01 / math.sqrt(2))
    assert width["f1_single_delta"] == pytest.approx(-0.008)            # below 2 x 0.0071, the seeds' spread
    assert width["f1_single_effect"] == "within noise"
    assert turns["latency_ms_ratio"] == 4.0 and turns["train_s_ratio"] == pytest.approx(1.0)
    assert int8["note"].startswith("not supported here: int8") and int8["f1_single"] is None


def test_peak_memory_sees_an_allocation_inside_its_body():
    with peak_memory() as before:
        pass
    with peak_memory() as mem:
        block = np.ones(64 * 2**20 // 8)             # 64 MB
        del block
    if before.mb is None:
        pytest.skip("this kernel cannot reset a process's peak memory (/proc/self/clear_refs)")
    assert mem.mb - before.mb > 50


def _tiny_imager():
    import torch

    from lesscli.bench.stream import default_imager

    torch.manual_seed(0)
    return default_imager(3, 0, 8)


def test_prediction_arithmetic_stays_close_to_float32_or_says_why_not():
    import torch

    from lesscli.bench.stream import synthetic_stream
    from lesscli.data.batching import collate

    imager, _ = _tiny_imager()
    pose, force = synthetic_stream(40, np.random.default_rng(0))
    batch = collate([{"pose": torch.from_numpy(pose), "force": torch.from_numpy(force.reshape(40, -1)),
                      "scan_index": 0}])
    cpu = torch.device("cpu")
    outs = {}
    for precision in tradeoff.PRECISIONS:
        with torch.no_grad(), tradeoff.prediction_arithmetic(imager, precision, cpu) as used:
            outs[precision] = used(batch).float()
    ref = outs["float32"]
    assert all(torch.isfinite(o).all() for o in outs.values())
    for precision, tol in (("bfloat16", 0.05), ("int8", 0.05)):
        err = (outs[precision] - ref).abs().max() / ref.abs().max()
        assert 0 < err < tol, (precision, float(err))                # changed, but only a little
    assert (outs["float32"] == ref).all()
    with pytest.raises(ValueError, match="CPU only"), tradeoff.prediction_arithmetic(imager, "int8",
                                                                                torch.device("meta")):
        pass
    with pytest.raises(ValueError, match="one of float32"), \
            tradeoff.prediction_arithmetic(imager, "fp8", cpu):
        pass


def test_classical_knobs_reach_its_calibration(tmp_path):
    """A fixed smoothing width and a coarser map cell are what the calibration stores and predicts with."""
    from factories import random_scanset

    from lesscli.infer import forcemap
    from lesscli.io.checkpoint import load_checkpoint
    from lesscli.train.forcemap_fit import fit_forcemap

    rng = np.random.default_rng(0)
    xy = rng.uniform(-20, 20, (400, 2))
    stiff = 1.0 + 0.5 * np.exp(-((xy ** 2).sum(axis=1)) / 20.0)
    touches = forcemap.Touches(xy, stiff, rng.integers(0, 30, 400))
    fine, coarse = forcemap.stiffness_map(touches, 2.0), forcemap.stiffness_map(touches, 2.0, 1.0)
    assert coarse.cell_mm == 1.0 and fine.cell_mm == forcemap.GRID_MM
    assert abs(coarse.residual.shape[0] * 2 - fine.residual.shape[0]) <= 2    # half the cells per side
    found_fine, found_coarse = forcemap.detect(fine, 2.0), forcemap.detect(coarse, 2.0)
    big_fine, big_coarse = (f[np.argmax(f[:, 2])] for f in (found_fine, found_coarse))   # the bump, both ways
    assert np.abs(big_fine[:2]).max() < 1.0 and np.abs(big_coarse[:2]).max() < 1.0
    assert abs(big_fine[2] - big_coarse[2]) < 1.0                         # the same size, in mm
    fit_forcemap(random_scanset(n_scans=3), str(tmp_path / "fm.pt"), sigmas_mm=(3.0,), grid_mm=1.0)

    cal = forcemap.calibration_from_dict(load_checkpoint(str(tmp_path / "fm.pt"))["config"]["forcemap"],
                                         "fm.pt")
    assert (cal.sigma_mm, cal.grid_mm) == (3.0, 1.0)
    old = {k: v for k,
           v in load_checkpoint(str(tmp_path / "fm.pt"))["config"]["forcemap"].items() if k != "grid_mm"}
    # older checkpoints read on
    assert forcemap.calibration_from_dict(old, "old.pt").grid_mm == forcemap.GRID_MM


def test_figures_are_non_blank_pngs(tmp_path):
    rows = [{"knob": "dim", "value": d, "train_s": d / 4, "latency_ms": d / 8, "f1_single": 0.3 + d / 1000,
             "f1_single_std": 0.01, "f1_multiple": 0.2} for d in (16, 32, 64)]
    rows.append({"knob": "reference", "value": "classical", "f1_single": 0.31, "f1_multiple": 0.25})
    pareto_figure(rows, str(tmp_path / "p.png"), time_key=("train_s", "latency_ms"))
    noise_figure([{"pos_mm": p, "ang_rad": a, "f1": 0.8 - p / 10 - a, "f1_std": 0.02}
                  for p in (0, 1, 2) for a in (0, 0.1)], str(tmp_path / "n.png"), metric="f1")
    line_figure([{"beta": b, "f1_single": b / 40, "f1_multiple": 0.5 - b / 100} for b in (5, 10, 20)],
                str(tmp_path / "l.png"), "beta", ["f1_single", "f1_multiple"], "receptive field, mm")
    for name in ("p.png", "n.png", "l.png"):
        _png_is_not_blank(tmp_path / name)


TINY = ("--family", "6", "--heldout", "2", "--multiple", "1", "--n-traj", "4", "--epochs", "1",
        "--image-epochs", "1", "--threads", "1")


def test_bench_tradeoff_tiny_run_end_to_end(tmp_path, run_less):
    proc = run_less("bench", "tradeoff", "--quick", "--knob", "width", "--values", "width=8", "--knob",
                    "precision", *TINY, "--work-dir", "w",
                    "--plot", "tradeoff.png", "--format", "jsonl", env=ONE_THREAD)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [(r["knob"], r["value"]) for r in rows] == [
        ("base", ""), ("width", 8), ("precision", "bfloat16"), ("precision", "int8"),
        ("reference", "classical"), ("reference", "average")]
    for r in rows[:4]:
        assert r["seeds"] == 2 and len(r["f1_single_seeds"]) == 2 and r["f1_single_std"] is not None
        assert r["train_s"] == pytest.approx(r["pretrain_s"] + r["fit_s"]) and r["latency_ms"] > 0
        assert r["stream_ms"] > 0 and 0.0 <= r["f1_single"] <= 1.0 and 0.0 <= r["f1_multiple"] <= 1.0
        assert r["ssl_epochs"] == 1 and r["image_epochs"] == 1 and r["model"] == "less-taxel"
        assert r["f1_single_effect"] in ("effect", "within noise")
    # the same model
    assert rows[0]["train_s_ratio"] == 1.0 and rows[2]["train_s_ratio"] == pytest.approx(1.0)
    assert rows[-1]["model"] == "average" and 0.0 <= rows[-1]["f1_single"] <= 1.0
    _png_is_not_blank(tmp_path / "tradeoff.png")
    stages = (tmp_path / "w" / "stages.jsonl").read_text().splitlines()
    again = run_less("bench", "tradeoff", "--quick", "--knob", "precision", *TINY, "--work-dir", "w",
                     "--format", "jsonl", env=ONE_THREAD)                     # resumes: nothing trained again
    assert again.returncode == 0, again.stderr.decode(errors="replace")
    resumed = [json.loads(line) for line in again.stdout.decode().splitlines()]
    assert resumed[0]["f1_single_seeds"] == rows[0]["f1_single_seeds"]
    assert resumed[0]["train_s"] == pytest.approx(rows[0]["train_s"])
    assert (tmp_path / "w" / "stages.jsonl").read_text().splitlines() == stages
    other = run_less("bench", "tradeoff", "--quick", "--knob", "precision", *TINY[:-2], "--n-traj", "5",
                     "--work-dir", "w")
    assert other.returncode == 1 and b"holds a run on other data" in other.stderr


def test_bench_tradeoff_of_the_classical_imager(tmp_path, run_less):
    proc = run_less("bench", "tradeoff", "--model", "forcemap", "--knob", "grid", "--values", "grid=1.0",
                    *TINY, "--format", "jsonl", env=ONE_THREAD)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [(r["model"], r["knob"], r["value"]) for r in rows] == [
        ("forcemap", "base", ""), ("forcemap", "grid", 1.0), ("average", "reference", "average")]
    assert rows[0]["seeds"] == 1 and rows[0]["f1_single_std"] == 0.0 and rows[0]["stream_ms"] is None


@pytest.mark.parametrize("args, message", [
    (("--knob", "recptive_field"), b"unknown knob 'recptive_field'"),
    (("--model", "global", "--knob", "spacing"), b"'spacing' does not apply to global"),
    (("--values", "dim=16,wide"), b"--values dim"),
    (("--values", "receptive=5"), b"KNOB=V1,V2"),
    (("--values", "precision=fp8"), b"float32 or bfloat16 or int8"),
    (("--values", "scans=1.5"), b"in (0, 1]"),
    (("--knob", "dim", "--knob", "width", "--knob-plot", "k.png"), b"exactly one --knob"),
])
def test_bench_tradeoff_checks_its_options_before_training(run_less, tmp_path, args, message):
    proc = run_less("bench", "tradeoff", "--quick", "--work-dir", "w", *args)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr
    assert not (tmp_path / "w").exists(), "a bad option must be caught before anything is simulated"
