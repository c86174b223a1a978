"""Accuracy against time: one knob at a time around a base setting, all on the same simulated data.

Knobs (``KNOBS``): simulator contact tier, receptive field beta (the paper's ablation), particle
spacing, state width d_z, image decoder width, subsampling rate, SSL training epochs and, at
prediction only, the turns averaged (``image predict --turns``). For each setting the run simulates
(once per tier, cached), subsamples, pretrains a LESS representation, fits a 3D image decoder (once
per trained setting: settings that differ only in ``turns`` share the model), predicts the held-out
``single`` inserts and the ``multiple`` set, and scores the inclusion class. Each row holds the times
(simulation, pretraining, image fitting, inference latency per scan) and the micro F1 on both sets, plus
ratios against the base setting measured in the same run.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

# knob name -> Setting field it varies
KNOBS: dict[str, str] = {"tier": "tier", "receptive_field": "receptive_field_mm", "spacing": "spacing_mm",
                         "dim": "dim", "width": "width", "subsample": "every", "epochs": "epochs",
                         "turns": "turns"}


@dataclass(frozen=True)
class Setting:
    """One trained configuration (the base, or the base with one knob changed)."""

    tier: str = "winkler"
    receptive_field_mm: float = 10.0
    spacing_mm: float = 6.0
    dim: int = 32
    width: int = 16             # channels of the image decoder's first feature map
    every: int = 50
    epochs: int = 10
    # prediction only: images averaged over the scan's turns (image predict --turns)
    turns: int = 1

    def trained(self) -> Setting:
        """The setting of the model it predicts with (prediction-only knobs at their base)."""
        return replace(self, turns=1)


@dataclass
class TradeoffPlan:
    """Sizes of a run: the data, the training and the values of each knob.

    Attributes:
        base: the setting every knob varies around.
        values: knob -> values tried (the base value is always included, and trained once).
        single_inserts / multiple_inserts: inserts simulated of each catalogue (first N).
        orientations: insert orientations simulated for ``single``.
        n_traj: pokes per scan.
        label_shape / label_spacing_mm: label grid (D, H, W) and (dz, dy, dx) mm of every set.
        image_epochs / lr / image_lr: imaging epochs, SSL and imaging learning rates.
        test_share: share of ``single`` inserts held out for testing.
    """

    base: Setting
    values: dict[str, tuple]
    single_inserts: int = 12
    multiple_inserts: int = 4
    orientations: tuple[int, ...] = (0, 4)
    n_traj: int = 30
    label_shape: tuple[int, int, int] = (13, 64, 64)
    label_spacing_mm: tuple[float, float, float] = (1.8, 0.9548, 0.9548)
    image_epochs: int = 40
    lr: float = 3e-3
    image_lr: float = 1e-2
    test_share: float = 0.25
    patch_px: int = 16


QUICK = TradeoffPlan(
    base=Setting(),
    values={"tier": ("winkler", "green"), "receptive_field": (5.0, 10.0, 20.0), "spacing": (6.0, 10.0),
            "dim": (16, 32), "width": (8, 16, 32), "subsample": (25, 50), "epochs": (4, 10), "turns": (1, 4)})
FULL = TradeoffPlan(
    base=Setting(tier="green", dim=128, width=32, epochs=100),
    values={"tier": ("winkler", "green", "fem"), "receptive_field": (5.0, 7.5, 10.0, 15.0, 20.0, 30.0),
            "spacing": (4.0, 6.0, 8.0, 10.0), "dim": (64, 128, 256, 512, 1024), "width": (16, 32, 64),
            "subsample": (10, 25, 50, 100),
            "epochs": (25, 50, 100, 200), "turns": (1, 2, 4)},
    single_inserts=30, multiple_inserts=10, orientations=(0, 2, 4, 6), n_traj=100, label_shape=(26, 128, 128),
    label_spacing_mm=(0.9, 0.4774, 0.4774), image_epochs=100, lr=1e-4, image_lr=1e-4, patch_px=32)



def make_plan(quick: bool, values: dict[str, tuple], epochs: int | None = None,
              **sizes: int | None) -> TradeoffPlan:
    """``QUICK`` or ``FULL`` with ``values`` replacing those knobs' values, ``epochs`` the base SSL epochs
    and ``sizes`` (``TradeoffPlan`` fields) replacing the plan's; None keeps the plan's own."""
    plan = QUICK if quick else FULL
    plan = replace(plan, **{k: v for k, v in sizes.items() if v is not None},
                   values={**plan.values, **values})
    if epochs:
        plan = replace(plan, base=replace(plan.base, epochs=epochs))
    return plan


@dataclass
class BenchData:
    """Raw (100 Hz) simulated scans of one tier, split by insert, and how long simulating took."""

    train: object
    test: object
    multiple: object
    sim_s: float


@dataclass
class TradeoffRun:
    """Everything a run needs besides the plan: where to work, device and seed."""

    workdir: str
    device: str = "cpu"
    seed: int = 0
    progress: Callable = field(default=lambda it, **_: it)


def settings_of(plan: TradeoffPlan, knobs: list[str]) -> list[tuple[str, object, Setting]]:
    """(knob, value, setting) for every value of every chosen knob, base values included."""
    out = []
    for knob in knobs:
        for value in plan.values[knob]:
            out.append((knob, value, replace(plan.base, **{KNOBS[knob]: value})))
    return out


def scene_doc(plan: TradeoffPlan, catalogue: str, tier: str, seed: int) -> dict:
    """A scene document for ``less simulate``'s engine: pokes over the first inserts of a catalogue."""
    n = plan.single_inserts if catalogue == "single" else plan.multiple_inserts
    return {"name": f"tradeoff-{catalogue}-{tier}", "seed": seed,
            "phantoms": {"set": catalogue, "limit": n,
                         "orientations": list(plan.orientations) if catalogue == "single" else [0]},
            "contact": {"tier": tier}, "motion": {"kind": "poke", "n_traj": plan.n_traj},
            "labels": {"shape": list(plan.label_shape), "spacing_mm": list(plan.label_spacing_mm)},
            "effects": {"tilt": {}, "sensor": {}, "noise": {}, "pose": {}}}


def make_data(plan: TradeoffPlan, tier: str, run: TradeoffRun) -> BenchData:
    """Simulate ``single`` (split by insert) and ``multiple`` with one contact tier."""
    from lesscli.data.ops import split
    from lesscli.sim.scene import parse_scene
    from lesscli.sim.simulate import simulate

    t0 = time.perf_counter()
    single = simulate(parse_scene(scene_doc(plan, "single", tier, run.seed), f"<tradeoff single {tier}>"))
    multiple = simulate(parse_scene(scene_doc(plan, "multiple", tier, run.seed + 1),
                                    f"<tradeoff multiple {tier}>"))
    sim_s = time.perf_counter() - t0
    parts = split(single, "insert", plan.test_share, 0.0, np.random.default_rng(run.seed), "tradeoff single")
    return BenchData(parts["train"], parts["test"], multiple, sim_s)


def train_setting(plan: TradeoffPlan, s: Setting, data: BenchData, run: TradeoffRun, stem: str) -> dict:
    """Pretrain and fit one setting; returns the imaging checkpoint path and the times."""
    from lesscli.data.ops import subsample
    from lesscli.train import distributed
    from lesscli.train.config import PretrainConfig, load_config
    from lesscli.train.image_fit import ImageFitConfig, fit_imager
    from lesscli.train.pretrain import pretrain

    train = subsample(data.train, every=s.every)
    env = distributed.DistEnv(device=distributed.resolve_device(run.device))
    pcfg = load_config(PretrainConfig, None, (), {
        "model.name": "less", "model.dim": s.dim, "model.receptive_field_mm": s.receptive_field_mm,
        "model.spacing_mm": s.spacing_mm, "train.epochs": s.epochs, "train.lr": plan.lr,
        "train.seed": run.seed, "train.device": run.device})
    rep, img = os.path.join(run.workdir, stem + "_rep.pt"), os.path.join(run.workdir, stem + "_img.pt")
    t0 = time.perf_counter()
    pretrain(train, None, pcfg, rep, env=env)
    t1 = time.perf_counter()
    icfg = load_config(ImageFitConfig, None, (), {
        "image.dim": 3, "image.patch_px": plan.patch_px, "image.width": s.width,
        "train.epochs": plan.image_epochs, "train.lr": plan.image_lr, "train.seed": run.seed,
        "train.device": run.device})
    fit_imager(train, None, rep, icfg, img, env=env)
    t2 = time.perf_counter()
    return {"imager": img, "pretrain_s": t1 - t0, "fit_s": t2 - t1, "train_steps": int(train.n_steps)}


def evaluate(imager_path: str, s: Setting, data: BenchData, run: TradeoffRun) -> dict:
    """Micro F1 (3D, inclusion) on the held-out single inserts and the multiple set; latency per scan."""
    from lesscli.data.ops import subsample
    from lesscli.infer.predict import PredictOptions, load_imager, predict
    from lesscli.metrics import score_prediction_set, summarise
    from lesscli.train.distributed import resolve_device

    dev = resolve_device(run.device)
    imager, ckpt = load_imager(imager_path, dev)
    out: dict = {}
    for name, scans in (("single", data.test), ("multiple", data.multiple)):
        scans = subsample(scans, every=s.every)
        t0 = time.perf_counter()
        preds = predict(imager, ckpt, scans, PredictOptions(turns=s.turns), dev, name=name)
        if name == "single":
            out["latency_ms_per_scan"] = 1e3 * (time.perf_counter() - t0) / max(1, scans.n_scans)
        summary = summarise(score_prediction_set(preds, name))[0]
        out[f"f1_{name}"] = summary.get("f1_micro_3d")
        out[f"com_error_mm_{name}"] = summary.get("com_error_mm_3d")
    return out


def _ratios(rows: list[dict], base: Setting) -> None:
    ref = next((r for r in rows if r["_setting"] == base), None)
    for r in rows:
        for key in ("train_s", "latency_ms_per_scan"):
            r[f"{key}_ratio"] = (r[key] / ref[key]) if ref and ref[key] else None
        for key in ("f1_single", "f1_multiple"):
            ok = ref is not None and r[key] is not None and ref[key] is not None
            r[f"{key}_delta"] = (r[key] - ref[key]) if ok else None


def run_tradeoff(plan: TradeoffPlan, knobs: list[str], run: TradeoffRun) -> list[dict]:
    """One row per (knob, value); a setting shared by several knobs is trained once.

    Returns:
        rows with ``knob``, ``value``, the setting's fields, ``sim_s`` (simulating this tier's
        data), ``pretrain_s``, ``fit_s``, ``train_s`` (their sum), ``latency_ms_per_scan``,
        ``f1_single``, ``f1_multiple`` (micro F1, 3D inclusion), centroid errors, and ratios /
        differences against the base setting.
    """
    os.makedirs(run.workdir, exist_ok=True)
    todo = settings_of(plan, knobs)
    if not any(s == plan.base for _, _, s in todo):
        todo.insert(0, ("base", "base", plan.base))
    data: dict[str, BenchData] = {}
    models: dict[Setting, dict] = {}
    done: dict[Setting, dict] = {}
    rows = []
    for knob, value, s in run.progress(todo, desc="settings", unit="setting"):
        if s.tier not in data:
            data[s.tier] = make_data(plan, s.tier, run)
        if s.trained() not in models:
            models[s.trained()] = train_setting(plan, s.trained(), data[s.tier], run, f"s{len(models):02d}")
        if s not in done:
            trained = models[s.trained()]
            done[s] = {**trained, **evaluate(trained["imager"], s, data[s.tier], run)}
        res = done[s]
        rows.append({"knob": knob, "value": value, **s.__dict__, "sim_s": data[s.tier].sim_s,
                     "pretrain_s": res["pretrain_s"], "fit_s": res["fit_s"],
                     "train_s": res["pretrain_s"] + res["fit_s"], "train_steps": res["train_steps"],
                     **{k: v for k, v in res.items() if k.startswith(("latency", "f1_", "com_"))},
                     "_setting": s})
    _ratios(rows, plan.base)
    for r in rows:
        r.pop("_setting")
    return rows
