"""Accuracy-vs-time bench: Pareto front, setting bookkeeping, and a tiny run of the command."""

import json

import pytest

from lesscli.bench import tradeoff
from lesscli.bench.tradeoff import FULL, KNOBS, QUICK, Setting, TradeoffRun, run_tradeoff, settings_of
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


def test_settings_vary_one_knob_around_the_base():
    found = settings_of(QUICK, ["receptive_field", "tier"])
    assert [(k, v) for k, v, _ in found] == [("receptive_field", 5.0), ("receptive_field", 10.0),
                                              ("receptive_field", 20.0), ("tier", "winkler"),
                                              ("tier", "green")]
    assert found[0][2] == Setting(receptive_field_mm=5.0) and found[4][2] == Setting(tier="green")
    assert found[1][2] == QUICK.base == found[3][2]


def test_every_knob_has_values_including_the_base_in_both_plans(run_less):
    for plan in (QUICK, FULL):
        assert set(plan.values) == set(KNOBS)
        for knob, values in plan.values.items():
            assert getattr(plan.base, KNOBS[knob]) in values, (knob, values)
    helptext = run_less("bench", "tradeoff", "--help").stdout.decode()
    assert all(knob in helptext for knob in KNOBS)


def test_a_setting_shared_by_two_knobs_is_trained_once_and_ratios_use_the_base(monkeypatch, tmp_path):
    trained, simulated = [], []
    monkeypatch.setattr(tradeoff, "make_data", lambda plan, tier, run: simulated.append(tier) or
                        tradeoff.BenchData(None, None, None, sim_s=1.0))

    def fake_train(plan, s, data, run, stem):
        trained.append(s)
        return {"imager": stem, "pretrain_s": s.dim / 8, "fit_s": 1.0, "train_steps": 10}

    monkeypatch.setattr(tradeoff, "train_setting", fake_train)
    monkeypatch.setattr(tradeoff, "evaluate", lambda path, s, data, run: {
        "latency_ms_per_scan": 2.0, "f1_single": s.receptive_field_mm / 100, "f1_multiple": 0.5})
    rows = run_tradeoff(QUICK, ["receptive_field", "dim"], TradeoffRun(workdir=str(tmp_path)))
    assert len(rows) == 5 and len(trained) == 4 and simulated == ["winkler"]
    base = [r for r in rows if r["receptive_field_mm"] == 10.0 and r["dim"] == 32]
    assert len(base) == 2 and all(r["train_s_ratio"] == 1.0 and r["f1_single_delta"] == 0.0 for r in base)
    dim16 = next(r for r in rows if r["knob"] == "dim" and r["value"] == 16)
    assert dim16["train_s"] == pytest.approx(3.0) and dim16["train_s_ratio"] == pytest.approx(3.0 / 5.0)
    rf20 = next(r for r in rows if r["value"] == 20.0)
    assert rf20["f1_single_delta"] == pytest.approx(0.1)


def test_turns_share_the_trained_model_and_are_evaluated_each(monkeypatch, tmp_path):
    trained, evaluated = [], []
    monkeypatch.setattr(tradeoff, "make_data", lambda plan, tier,
                        run: tradeoff.BenchData(None, None, None, 1.0))
    monkeypatch.setattr(tradeoff, "train_setting", lambda plan, s, data, run, stem: trained.append(s) or {
        "imager": stem, "pretrain_s": 2.0, "fit_s": 1.0, "train_steps": 10})
    monkeypatch.setattr(tradeoff, "evaluate", lambda path, s, data,
                        run: evaluated.append((path, s.turns)) or {
        "latency_ms_per_scan": 2.0 * s.turns, "f1_single": 0.5 + s.turns / 100, "f1_multiple": 0.5})
    rows = run_tradeoff(QUICK, ["turns"], TradeoffRun(workdir=str(tmp_path)))
    assert trained == [QUICK.base] and evaluated == [("s00", 1), ("s00", 4)]
    four = next(r for r in rows if r["value"] == 4)
    assert four["train_s_ratio"] == 1.0 and four["latency_ms_per_scan_ratio"] == 4.0
    assert four["f1_single_delta"] == pytest.approx(0.03)


def test_figures_are_non_blank_pngs(tmp_path):
    rows = [{"knob": "dim", "value": d, "train_s": d / 4, "f1_single": 0.3 + d / 1000, "f1_multiple": 0.2}
            for d in (16, 32, 64)]
    pareto_figure(rows, str(tmp_path / "p.png"))
    noise_figure([{"pos_mm": p, "ang_rad": a, "f1": 0.8 - p / 10 - a, "f1_std": 0.02}
                  for p in (0, 1, 2) for a in (0, 0.1)], str(tmp_path / "n.png"), metric="f1")
    line_figure([{"beta": b, "f1_single": b / 40, "f1_multiple": 0.5 - b / 100} for b in (5, 10, 20)],
                str(tmp_path / "l.png"), "beta", ["f1_single", "f1_multiple"], "receptive field, mm")
    for name in ("p.png", "n.png", "l.png"):
        _png_is_not_blank(tmp_path / name)


def test_bench_tradeoff_tiny_run_end_to_end(tmp_path, run_less):
    proc = run_less("bench", "tradeoff", "--quick", "--knob", "receptive_field", "--values",
                    "receptive_field=5,10", "--inserts", "4", "--n-traj", "4", "--epochs", "1",
                    "--image-epochs", "1", "--threads", "1", "--plot", "tradeoff.png", "--format", "jsonl",
                    env=ONE_THREAD)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [(r["knob"], r["value"]) for r in rows] == [("receptive_field", 5.0), ("receptive_field", 10.0)]
    for r in rows:
        assert r["train_s"] == pytest.approx(r["pretrain_s"] + r["fit_s"]) and r["latency_ms_per_scan"] > 0
        assert 0.0 <= r["f1_single"] <= 1.0 and 0.0 <= r["f1_multiple"] <= 1.0
        assert r["epochs"] == 1 and r["tier"] == "winkler"
    assert rows[1]["train_s_ratio"] == 1.0
    _png_is_not_blank(tmp_path / "tradeoff.png")


def test_bench_tradeoff_rejects_an_unknown_knob(run_less):
    proc = run_less("bench", "tradeoff", "--quick", "--knob", "recptive_field")
    assert proc.returncode == 2 and b"receptive_field" in proc.stderr


@pytest.mark.parametrize("args, message", [
    (("--values", "dim=16,wide"), b"--values dim"),
    (("--values", "receptive=5"), b"KNOB=V1,V2"),
    (("--knob", "dim", "--knob", "epochs", "--knob-plot", "k.png"), b"exactly one --knob"),
])
def test_bench_tradeoff_checks_its_options_before_training(run_less, tmp_path, args, message):
    proc = run_less("bench", "tradeoff", "--quick", "--work-dir", "w", *args)
    assert proc.returncode == 2 and message in proc.stderr
    assert not (tmp_path / "w").exists(), "a bad option must be caught before anything is simulated"
