"""Accuracy against time around the demo's imager: one knob at a time, every setting over several seeds.

The data are the demo's (examples/demo.sh): the quick scene's randomised training family with a
validation share split off by insert, the 16 held-out catalogue inserts at two orientations
(``single``) and the catalogue's multiple-inclusion inserts (``multiple``), simulated once per run.
Each imager starts from its own base (``BASES``). A knob (``KNOBS``) changes one setting; a
setting that differs from a trained one only in its decoder reuses that representation, one that
differs only at prediction reuses the trained model. A row holds, over the seeds, the mean and
spread of F1 on both sets and of the centroid error, the training time, the whole-scan and
streaming-update latencies and the peak memory, each also against the base measured in the same
run; a change of F1 counts as an effect only beyond twice the seeds' spread.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from lesscli.bench.timing import best_time, peak_memory

CLASSICAL = "forcemap"
LEARNED = ("less-taxel", "less", "global", "global-taxel")
MODELS = (*LEARNED, CLASSICAL)
LOCAL = ("less-taxel", "less")                  # particles with a receptive field and a spacing
TAXEL = ("less-taxel", "global-taxel")          # per-step stiffness maps
PRECISIONS = ("float32", "bfloat16", "int8")
# linear layers an encoder reads as tensors (folded into its GRU)
STREAM_UPDATES = 200                            # streaming updates timed per seed (after half a scan)
LATENCY_REPEATS = 3                             # whole-set predictions timed per seed (the best is kept)
EFFECT_SPREADS = 2.0                            # an effect exceeds this many seed spreads
# the demo's held-out catalogue inserts (examples/demo.sh), every size and family, orientations 0 and 4
HELDOUT = ("St8C5", "St8C9", "St8D13", "St10C9", "St10D5", "St10D13", "St12C5", "St12C13", "St12D9", "St14C5",
           "St14D9", "St14D13", "St16C9", "St16C13", "St16D5", "St16D9")


@dataclass(frozen=True)
class Setting:
    """One imager's configuration: what it is trained with and how it predicts."""

    model: str = "less-taxel"
    # representation (less pretrain)
    dim: int = 16
    receptive_field_mm: float = 10.0
    spacing_mm: float = 6.0
    map_cells: int = 7
    map_pitch_mm: float = 2.5
    map_contrast: str = "step"
    ssl_epochs: int = 8
    ssl_lr: float = 3e-3
    # training data
    scans: float = 1.0          # share of the training inserts used
    pokes: int = 0              # pokes kept per training scan (0: all)
    every: int = 50             # subsampling of the 100 Hz scans (1:N), for training and prediction
    # decoder (less image fit)
    width: int = 16
    image_epochs: int = 40
    image_lr: float = 1e-2
    alpha_power: float = 0.5
    # classical imager (less image fit --model forcemap)
    sigma_mm: float = 0.0       # smoothing width (0: chosen by its calibration)
    grid_mm: float = 0.5        # force-map cell
    # prediction only
    turns: int = 1
    predict_every: int = 0      # subsampling at prediction only (0: as trained)
    threads: int = 0            # prediction threads (0: the run's)
    precision: str = "float32"


PREDICT_FIELDS = ("turns", "predict_every", "threads", "precision")
DECODER_FIELDS = ("width", "image_epochs", "image_lr", "alpha_power")
DEFAULTS = Setting()


def trained(s: Setting) -> Setting:
    """The setting of the model ``s`` predicts with (prediction-only fields at their defaults)."""
    return replace(s, **{f: getattr(DEFAULTS, f) for f in PREDICT_FIELDS})


def represented(s: Setting) -> Setting:
    """The setting of the representation ``s`` decodes (decoder fields at their defaults too)."""
    return replace(trained(s), **{f: getattr(DEFAULTS, f) for f in DECODER_FIELDS})


# Each imager's own base. less-taxel: the demo's settings (examples/demo.sh); less, global and
# global-taxel: those their search chose on validation scans (examples/tuning/winkler/), with the demo's
# 40 imaging epochs; the classical imager: its own calibration.
BASES = {
    "less-taxel": Setting(),
    "less": Setting(model="less", dim=64, ssl_epochs=20, ssl_lr=1e-3),
    "global": Setting(model="global", dim=16, ssl_epochs=20, ssl_lr=1e-3, width=32, image_lr=1e-3,
                      alpha_power=1.0),
    "global-taxel": Setting(model="global-taxel", dim=64, ssl_epochs=20, ssl_lr=1e-3),
    "forcemap": Setting(model=CLASSICAL),
}


@dataclass(frozen=True)
class Knob:
    """A setting field varied around the base, the imagers it applies to, and what it is."""

    field: str
    models: tuple[str, ...]
    help: str


KNOBS: dict[str, Knob] = {          # in the order a run measures them: prediction first, the dearest last
    "turns": Knob("turns", LEARNED, "turns averaged at prediction"),
    "predict_subsample": Knob("predict_every", MODELS, "subsampling 1:N at prediction only"),
    "threads": Knob("threads", MODELS, "prediction threads"),
    "precision": Knob("precision", LEARNED, "prediction arithmetic: float32, bfloat16, int8 (dynamic)"),
    "smoothing": Knob("sigma_mm", (CLASSICAL,), "force-map smoothing width, mm (0: calibrated)"),
    "grid": Knob("grid_mm", (CLASSICAL,), "force-map cell, mm"),
    "subsample": Knob("every", MODELS, "subsampling 1:N, training and prediction"),
    "scans": Knob("scans", MODELS, "share of the training inserts used"),
    "pokes": Knob("pokes", MODELS, "pokes per training scan"),
    "ssl_epochs": Knob("ssl_epochs", LEARNED, "self-supervised epochs"),
    "width": Knob("width", LEARNED, "image decoder width"),
    "dim": Knob("dim", LEARNED, "GRU state width d_z"),
    "spacing": Knob("spacing_mm", LOCAL, "particle spacing, mm"),
    "receptive_field": Knob("receptive_field_mm", LOCAL, "particle receptive field beta, mm"),
    "map_cells": Knob("map_cells", TAXEL, "stiffness-map cells per side"),
    "map_pitch": Knob("map_pitch_mm", TAXEL, "stiffness-map pitch, mm"),
    "contrast": Knob("map_contrast", TAXEL, "stiffness-map contrast rule (step, plane)"),
}


# knob -> (test of a value, the rule in words) for values given on the command line
VALUE_RULES: dict[str, tuple[Callable, str]] = {
    **{k: (lambda v: v > 0, "> 0") for k in ("receptive_field", "spacing", "map_pitch", "grid")},
    **{k: (lambda v: v >= 1, ">= 1") for k in ("map_cells", "dim", "ssl_epochs", "pokes", "subsample",
                                                 "predict_subsample", "threads")},
    "width": (lambda v: v >= 8, ">= 8"), "scans": (lambda v: 0 < v <= 1, "in (0, 1]"),
    "smoothing": (lambda v: v >= 0, ">= 0 (0: calibrated)"), "turns": (lambda v: v in (1, 2, 4), "1, 2 or 4"),
    "contrast": (lambda v: v in ("step", "plane"), "step or plane"),
    "precision": (lambda v: v in PRECISIONS, " or ".join(PRECISIONS)),
}


def knobs_for(model: str) -> list[str]:
    """The knobs that apply to ``model``, in ``KNOBS`` order."""
    return [k for k, knob in KNOBS.items() if model in knob.models]


@dataclass(frozen=True)
class TradeoffPlan:
    """What a run tries and on how much data.

    Attributes:
        values: knob -> values tried besides the base's own.
        seeds: training seeds per setting (the classical imager is deterministic: one).
        family: randomised training inserts (the quick scene's 120: the demo's).
        heldout: catalogue single inserts imaged (two orientations each).
        multiple: catalogue multiple-inclusion inserts imaged (one orientation).
        n_traj: pokes per scan simulated.
        ssl_epochs / image_epochs: replace every setting's epochs (None: the settings' own).
    """

    values: dict[str, tuple]
    seeds: int
    family: int = 120
    heldout: tuple[str, ...] = HELDOUT
    multiple: int = 10
    n_traj: int = 30
    ssl_epochs: int | None = None
    image_epochs: int | None = None

    def base_of(self, model: str) -> Setting:
        """The model's base with the plan's epochs."""
        base = BASES[model]
        if self.ssl_epochs:
            base = replace(base, ssl_epochs=self.ssl_epochs)
        return replace(base, image_epochs=self.image_epochs) if self.image_epochs else base


# --quick: the base and every prediction knob over 2 seeds (about 15 min on 2 cores; the classical imager's
# calibration knobs too, with --model forcemap)
QUICK = TradeoffPlan(
    values={"turns": (4,), "predict_subsample": (100,), "threads": (1,), "precision": ("bfloat16", "int8"),
            "smoothing": (2.0,), "grid": (1.0,)},
    seeds=2)
# the full plan: every knob, 3 seeds (a rerun with the same --work-dir resumes where one stopped)
FULL = TradeoffPlan(
    values={"turns": (2, 4), "predict_subsample": (100,), "threads": (1,), "precision": ("bfloat16", "int8"),
            "smoothing": (1.5, 3.0), "grid": (0.25, 1.0), "subsample": (100,), "scans": (0.5,),
            "pokes": (15,), "ssl_epochs": (2,), "width": (8,), "dim": (32,), "spacing": (10.0,),
            "receptive_field": (15.0,), "map_cells": (5,), "map_pitch": (3.5,), "contrast": ("plane",)},
    seeds=3)


def make_plan(quick: bool, values: dict[str, tuple], **sizes) -> TradeoffPlan:
    """``QUICK`` or ``FULL`` with ``values`` replacing those knobs' values and ``sizes`` (``TradeoffPlan``
    fields) replacing the plan's; None keeps the plan's own."""
    plan = QUICK if quick else FULL
    return replace(plan, **{k: v for k, v in sizes.items() if v is not None},
                   values={**plan.values, **values})


def settings_of(plan: TradeoffPlan, model: str, knobs: list[str]) -> list[tuple[str, object, Setting]]:
    """(knob, value, setting): the base first, then every other value of every chosen knob."""
    base = plan.base_of(model)
    out: list[tuple[str, object, Setting]] = [("base", "", base)]
    for knob in knobs:
        name = KNOBS[knob].field
        for value in plan.values.get(knob, ()):
            if value != getattr(base, name):
                out.append((knob, value, replace(base, **{name: value})))
    return out


@dataclass
class BenchData:
    """The run's 100 Hz scans: training and validation parts of the family, the two test sets, and
    how long simulating them took."""

    train: object
    val: object
    single: object
    multiple: object
    sim_s: float


@dataclass
class TradeoffRun:
    """Everything a run needs besides the plan: where to work, device, first seed and a progress wrapper."""

    workdir: str
    device: str = "cpu"
    seed: int = 0
    progress: Callable = field(default=lambda it, **_: it)


def _scene(plan: TradeoffPlan, sets: list[str]):
    from lesscli.scenes import resolve
    from lesscli.sim.scene import load_scene

    return load_scene(resolve("quick"), [f"motion.n_traj={plan.n_traj}", *sets])


DATA_PARTS = ("train", "val", "single", "multiple")


def make_data(plan: TradeoffPlan, workdir: str | None = None) -> BenchData:
    """Simulate the demo's data with the plan's sizes (the scene's own seed: the same data every run);
    with ``workdir``, kept there and read back by a rerun of the same sizes."""
    from lesscli.data.ops import split
    from lesscli.errors import DataError
    from lesscli.io.scans import load_scans, save_scans
    from lesscli.sim.simulate import simulate
    from lesscli.threads import usable_cores

    sizes = {"family": plan.family, "heldout": list(plan.heldout), "multiple": plan.multiple,
             "n_traj": plan.n_traj}
    index = os.path.join(workdir, "data.json") if workdir else None
    if index and os.path.exists(index):
        with open(index) as f:
            kept = json.load(f)
        if kept["sizes"] != sizes:
            raise DataError(f"{workdir}: holds a run on other data ({kept['sizes']}); use another --work-dir")
        return BenchData(*(load_scans(os.path.join(workdir, f"data-{p}.npz")) for p in DATA_PARTS),
                         kept["sim_s"])
    jobs = usable_cores()
    t0 = time.perf_counter()
    family = simulate(_scene(plan, [f"phantoms.random.count={plan.family}"]), jobs=jobs)
    single = simulate(_scene(plan, ["phantoms.set=single", f"phantoms.names={json.dumps(list(plan.heldout))}",
                                    "phantoms.orientations=[0,4]"]), jobs=jobs)
    multiple = simulate(_scene(plan, ["phantoms.set=multiple", f"phantoms.limit={plan.multiple}"]), jobs=jobs)
    sim_s = time.perf_counter() - t0
    parts = split(family, "insert", 0.15, 0.0, np.random.default_rng(0), "tradeoff family")   # as the demo
    data = BenchData(parts["train"], parts["test"], single, multiple, sim_s)
    if index:
        for p in DATA_PARTS:
            save_scans(os.path.join(workdir, f"data-{p}.npz"), getattr(data, p))
        with open(index, "w") as f:
            json.dump({"sizes": sizes, "sim_s": sim_s}, f)
    return data


def setting_scans(data: BenchData, s: Setting) -> tuple[object, object]:
    """The training and validation scans of setting ``s``, subsampled and in their surface frame."""
    from lesscli.data.compat import prepare
    from lesscli.data.ops import subsample

    train = data.train
    if s.scans < 1.0:
        inserts = list(dict.fromkeys(train.scan_insert))
        keep = set(np.random.default_rng(0).permutation(inserts)[:max(1, round(s.scans * len(inserts)))])
        train = train.select_scans(np.array([i for i, name in enumerate(train.scan_insert) if name in keep]))
    train = subsample(train, every=s.every, trajectories=s.pokes or None, rng=np.random.default_rng(0))
    return prepare(train, "tradeoff training"), prepare(subsample(data.val, every=s.every),
                                                        "tradeoff validation")


def eval_scans(data: BenchData, s: Setting) -> dict[str, object]:
    """The two test sets at the setting's prediction rate, in their surface frame."""
    from lesscli.data.compat import prepare
    from lesscli.data.ops import subsample

    every = s.predict_every or s.every
    return {name: prepare(subsample(scans, every=every), f"tradeoff {name}")
            for name, scans in (("single", data.single), ("multiple", data.multiple))}


def _pretrain(s: Setting, seed: int, train, val, run: TradeoffRun, path: str) -> None:
    from lesscli.train import distributed
    from lesscli.train.config import PretrainConfig, load_config
    from lesscli.train.pretrain import pretrain

    cfg = load_config(PretrainConfig, None, (), {
        "model.name": s.model, "model.dim": s.dim, "model.receptive_field_mm": s.receptive_field_mm,
        "model.spacing_mm": s.spacing_mm, "model.map_cells": s.map_cells,
        "model.map_pitch_mm": s.map_pitch_mm, "model.map_contrast": s.map_contrast,
        "train.epochs": s.ssl_epochs, "train.lr": s.ssl_lr, "train.batch_size": 4, "ssl.k_input": 8,
        "ssl.k_query": 8, "train.seed": seed, "train.device": run.device})
    pretrain(train, val, cfg, path, env=distributed.DistEnv(device=distributed.resolve_device(run.device)))


def _fit(s: Setting, seed: int, train, val, rep: str, run: TradeoffRun, path: str) -> None:
    from lesscli.train import distributed
    from lesscli.train.config import load_config
    from lesscli.train.image_fit import ImageFitConfig, fit_imager

    cfg = load_config(ImageFitConfig, None, (), {
        "image.dim": 3, "image.patch_px": 16, "image.width": s.width, "loss.alpha_power": s.alpha_power,
        "train.epochs": s.image_epochs, "train.lr": s.image_lr, "train.batch_size": 4, "train.seed": seed,
        "train.device": run.device})
    fit_imager(train, val, rep, cfg, path,
               env=distributed.DistEnv(device=distributed.resolve_device(run.device)))


class Store:
    """The finished stages of a run, one JSON line each in its work folder (``stages.jsonl``): a rerun
    with the same ``--work-dir`` takes them from there instead of training and measuring again."""

    def __init__(self, workdir: str) -> None:
        self.path = os.path.join(workdir, "stages.jsonl")
        self.done: dict[str, dict] = {}
        if os.path.exists(self.path):
            with open(self.path) as f:
                for line in f:
                    if line.strip():
                        item = json.loads(line)
                        self.done[item["key"]] = item["value"]

    @staticmethod
    def key(kind: str, s: Setting, seed: int) -> str:
        return json.dumps([kind, asdict(s), seed], sort_keys=True)

    def get(self, key: str, files: tuple[str, ...] = ()) -> dict | None:
        """The stage's record, if it finished and the files it names are still there."""
        value = self.done.get(key)
        ok = value is not None and all(os.path.exists(value[f]) for f in files)
        return value if ok else None

    def put(self, key: str, value: dict) -> dict:
        self.done[key] = value
        with open(self.path, "a") as f:
            f.write(json.dumps({"key": key, "value": value}) + "\n")
        return value

    def file(self, kind: str, key: str) -> str:
        return os.path.join(os.path.dirname(self.path),
                            f"{kind}-{hashlib.sha1(key.encode()).hexdigest()[:12]}.pt")


class Trainer:
    """Trains settings once per seed, sharing a representation between settings that differ only in
    their decoder; each result carries the full training time of its setting (shared stages included)."""

    def __init__(self, data: BenchData, run: TradeoffRun, store: Store) -> None:
        self.data, self.run, self.store = data, run, store

    def model(self, s: Setting, seed: int) -> dict:
        """``{"path", "pretrain_s", "fit_s", "peak_train_mb"}`` of the trained model of ``s``."""
        key = Store.key("model", trained(s), seed)
        return self.store.get(key, ("path",)) or self.store.put(key, self._train(trained(s), seed, key))

    def _train(self, s: Setting, seed: int, key: str) -> dict:
        from lesscli.train.forcemap_fit import fit_forcemap

        train, val = setting_scans(self.data, s)
        path = self.store.file("imager", key)
        if s.model == CLASSICAL:
            sigmas = (s.sigma_mm,) if s.sigma_mm else None
            with peak_memory() as mem:
                t0 = time.perf_counter()
                fit_forcemap(train, path, 3, None, "tradeoff training",
                             **({"sigmas_mm": sigmas} if sigmas else {}), grid_mm=s.grid_mm)
            return {"path": path, "pretrain_s": 0.0, "fit_s": time.perf_counter() - t0,
                    "peak_train_mb": mem.mb}
        rkey = Store.key("representation", represented(s), seed)
        rep = self.store.get(rkey, ("path",))
        if rep is None:
            rep_path = self.store.file("rep", rkey)
            with peak_memory() as mem:
                t0 = time.perf_counter()
                _pretrain(s, seed, train, val, self.run, rep_path)
            rep = self.store.put(rkey,
                                 {"path": rep_path, "pretrain_s": time.perf_counter() - t0,
                                  "peak_mb": mem.mb})
        with peak_memory() as mem:
            t0 = time.perf_counter()
            _fit(s, seed, train, val, rep["path"], self.run, path)
        return {"path": path, "pretrain_s": rep["pretrain_s"], "fit_s": time.perf_counter() - t0,
                "peak_train_mb": _max(rep["peak_mb"], mem.mb)}


def _max(*values):
    known = [v for v in values if v is not None]
    return max(known) if known else None


@contextmanager
def prediction_arithmetic(imager, precision: str, device) -> Iterator:
    """The imager to predict with under ``precision``: float32 as it is, bfloat16 under autocast,
    int8 a copy with its linear layers dynamically quantised (CPU only; the GRU runs its own ragged
    recurrence on the float weights and the decoder's convolutions stay float). Raises ValueError
    where this torch or device cannot."""
    import torch

    if precision == "float32":
        yield imager
    elif precision == "bfloat16":
        with torch.autocast(device.type, dtype=torch.bfloat16):
            yield imager
    elif precision == "int8":
        if device.type != "cpu":
            raise ValueError("int8 dynamic quantisation runs on the CPU only")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")         # torch.ao.quantization announces its own deprecation
            try:
                from torch.ao.quantization import quantize_dynamic
            except ImportError as exc:
                raise ValueError(f"this torch has no dynamic quantisation ({exc})") from None
            quantized = quantize_dynamic(copy.deepcopy(imager), {torch.nn.Linear}, dtype=torch.qint8)
        yield quantized
    else:
        raise ValueError(f"unknown precision {precision!r}; one of {', '.join(PRECISIONS)}")


@contextmanager
def prediction_threads(n: int) -> Iterator[None]:
    """``n`` torch threads over the body (0: leave them), restored after."""
    import torch

    before = torch.get_num_threads()
    if n:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def stream_update_ms(imager, norm_stats: dict, scans) -> float:
    """Median milliseconds of one streaming update (``less stream``'s imager) over the second half of
    the first scan (at most ``STREAM_UPDATES`` samples), after priming it with the first half."""
    from lesscli.infer.stream import StreamingImager

    steps = scans.scan_steps(0)
    pose, force = scans.pose[steps], scans.force[steps]
    half = len(pose) // 2
    stream = StreamingImager(imager, norm_stats)
    stream.prime(pose[:half], force[:half])
    times = []
    for i in range(half, min(len(pose), half + STREAM_UPDATES)):
        t0 = time.perf_counter()
        stream.push(pose[i], force[i])              # GRU steps, patch re-decode and canvas, as bench stream
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times)) if times else float("nan")


def _scores(preds, name: str) -> dict:
    from lesscli.metrics import score_prediction_set, summarise

    summary = summarise(score_prediction_set(preds, name))[0]
    return {f"f1_{name}": summary.get("f1_micro_3d"), f"com_error_mm_{name}": summary.get("com_error_mm_3d")}


@contextmanager
def predicting(model: dict, s: Setting, device) -> Iterator[tuple[Callable, tuple | None]]:
    """(a function (set name, scans) -> predictions, and (imager, norm stats) to stream with, None for
    the classical imager) of a trained model under ``s``'s prediction threads and arithmetic."""
    from lesscli.infer.predict import PredictOptions, load_imager, predict, predict_forcemap
    from lesscli.io.checkpoint import load_checkpoint

    opts = PredictOptions(turns=s.turns)
    with prediction_threads(s.threads):
        if s.model == CLASSICAL:
            ckpt = load_checkpoint(model["path"])
            yield (lambda name, scans: predict_forcemap(ckpt, scans, opts, model["path"], name)), None
            return
        imager, ckpt = load_imager(model["path"], device)
        with prediction_arithmetic(imager, s.precision, device) as used:
            yield ((lambda name, scans: predict(used, ckpt, scans, opts, device, name=name)),
                   (used, ckpt["norm_stats"]))


def evaluate(model: dict, s: Setting, data: BenchData, run: TradeoffRun) -> dict:
    """Scores and costs of one trained model predicting under ``s``'s prediction settings: F1 and
    centroid error on both sets, the best of ``LATENCY_REPEATS`` whole-set predictions of ``single``
    per scan, the peak memory of predicting it and the streaming update latency."""
    from functools import partial

    from lesscli.train.distributed import resolve_device

    device = resolve_device(run.device)
    sets, out = eval_scans(data, s), {}
    with predicting(model, s, device) as (predict_set, streamer):
        for name, scans in sets.items():
            with peak_memory() as mem:
                seconds, preds = best_time(partial(predict_set, name, scans),
                                           LATENCY_REPEATS if name == "single" else 1)
            if name == "single":
                out.update(latency_ms=1e3 * seconds / scans.n_scans, peak_predict_mb=mem.mb)
            out.update(_scores(preds, name))
        if streamer:
            out["stream_ms"] = stream_update_ms(*streamer, sets["single"])
    return out


def average_reference(data: BenchData, run: TradeoffRun, classical: dict) -> dict:
    """The average-prediction baseline's scores on both sets (the training-mean sphere), read on the
    classical imager's predictions' truths."""
    from lesscli.infer.predict import PredictOptions, predict_forcemap
    from lesscli.io.checkpoint import load_checkpoint
    from lesscli.metrics import summarise
    from lesscli.metrics.baseline import average_baseline
    from lesscli.metrics.score import score_baseline_set

    train, _ = setting_scans(data, BASES[CLASSICAL])
    baseline = average_baseline(v for v in (train.label_of(i) for i in range(train.n_scans)) if v is not None)
    ckpt, out = load_checkpoint(classical["path"]), {}
    for name, scans in eval_scans(data, BASES[CLASSICAL]).items():
        preds = predict_forcemap(ckpt, scans, PredictOptions(), classical["path"], name)
        summary = summarise(score_baseline_set(preds, baseline, name))[0]
        out.update({f"f1_{name}": summary.get("f1_micro_3d"),
                    f"com_error_mm_{name}": summary.get("com_error_mm_3d")})
    return out


MEANS = ("f1_single", "f1_multiple", "com_error_mm_single", "com_error_mm_multiple", "pretrain_s", "fit_s",
         "train_s", "latency_ms", "stream_ms", "peak_train_mb", "peak_predict_mb")
SPREADS = ("f1_single", "f1_multiple", "com_error_mm_single")
RATIOS = ("train_s", "latency_ms", "stream_ms", "peak_train_mb", "peak_predict_mb", "com_error_mm_single")


def _mean(values: list) -> float | None:
    known = [float(v) for v in values if v is not None and np.isfinite(float(v))]
    return float(np.mean(known)) if known else None


def _std(values: list) -> float | None:
    known = [float(v) for v in values if v is not None and np.isfinite(float(v))]
    return float(np.std(known, ddof=1)) if len(known) > 1 else (0.0 if known else None)


def aggregate(per_seed: list[dict]) -> dict:
    """Mean over seeds of every measured key, the spread (sample std) of the scores, the seeds' F1."""
    out = {"seeds": len(per_seed)}
    for key in MEANS:
        out[key] = _mean([r.get(key) for r in per_seed])
    for key in SPREADS:
        out[f"{key}_std"] = _std([r.get(key) for r in per_seed])
    out["f1_single_seeds"] = [r.get("f1_single") for r in per_seed]
    return out


def effect(delta: float | None, spread_a: float | None, spread_b: float | None) -> str | None:
    """``"effect"`` where ``|delta|`` exceeds ``EFFECT_SPREADS`` times the larger seed spread, else
    ``"within noise"`` (None without a delta)."""
    if delta is None:
        return None
    spread = max(spread_a or 0.0, spread_b or 0.0)
    return "effect" if abs(delta) > EFFECT_SPREADS * spread else "within noise"


def compare_to_base(rows: list[dict]) -> None:
    """Ratios and F1 differences of every row against its model's base row, and whether each
    difference is an effect (:func:`effect`)."""
    bases = {r["model"]: r for r in rows if r["knob"] == "base"}
    for r in rows:
        ref = bases.get(r["model"])
        for key in RATIOS:
            ok = ref is not None and r.get(key) is not None and ref.get(key)
            r[f"{key}_ratio"] = r[key] / ref[key] if ok else None
        for key in ("f1_single", "f1_multiple"):
            ok = ref is not None and r.get(key) is not None and ref.get(key) is not None
            r[f"{key}_delta"] = r[key] - ref[key] if ok else None
            r[f"{key}_effect"] = effect(r[f"{key}_delta"], r.get(f"{key}_std"), ref.get(f"{key}_std")
                                        if ref else None)


def run_tradeoff(plan: TradeoffPlan, model: str, knobs: list[str], run: TradeoffRun,
                 data: BenchData | None = None) -> list[dict]:
    """One row per setting of ``model`` (its base first), then the reference rows: the classical
    imager at its base (unless it is the model) and the average-prediction baseline.

    Returns:
        rows with ``model``, ``knob``, ``value``, the setting's fields, ``seeds``, the means of
        ``MEANS`` over seeds, spreads ``<key>_std`` of ``SPREADS``, ``<key>_ratio`` of ``RATIOS`` and
        ``f1_<set>_delta`` / ``f1_<set>_effect`` against the base, ``sim_s`` and a ``note`` where a
        setting cannot run here (e.g. a precision this torch lacks).
    """
    os.makedirs(run.workdir, exist_ok=True)
    data = data or make_data(plan, run.workdir)
    store = Store(run.workdir)
    trainer = Trainer(data, run, store)
    seeds = [run.seed] if model == CLASSICAL else [run.seed + k for k in range(plan.seeds)]
    rows = []
    for knob, value, s in run.progress(settings_of(plan, model, knobs), desc="settings", unit="setting"):
        per_seed, note = [], None
        for seed in seeds:
            trained_model = trainer.model(s, seed)
            key = Store.key("scores", s, seed)
            scores = store.get(key) or store.put(key, _scores_or_note(trained_model, s, data, run))
            note = scores.get("note") or note
            per_seed.append({**trained_model, "train_s": trained_model["pretrain_s"] + trained_model["fit_s"],
                             **scores})
        row = {"model": model, "knob": knob, "value": value, **aggregate(per_seed), "sim_s": data.sim_s,
               "note": note, **asdict(s)}
        if note:
            row.update({k: None for k in ("f1_single", "f1_multiple", "latency_ms", "stream_ms")})
        rows.append(row)
    compare_to_base(rows)
    rows.extend(reference_rows(model, data, run, trainer))
    return rows


def _scores_or_note(model: dict, s: Setting, data: BenchData, run: TradeoffRun) -> dict:
    """:func:`evaluate`, or a ``note`` saying why this setting cannot run here (e.g. a precision)."""
    try:
        return evaluate(model, s, data, run)
    except (ValueError, RuntimeError, NotImplementedError) as exc:
        return {"note": f"not supported here: {str(exc).splitlines()[0][:160]}"}


DETERMINISTIC = {f"{key}_std": 0.0 for key in SPREADS}       # the references have no seed to vary


def reference_rows(model: str, data: BenchData, run: TradeoffRun, trainer: Trainer) -> list[dict]:
    """The classical imager at its base and the average-prediction baseline, for every table."""
    classical = trainer.model(BASES[CLASSICAL], run.seed)
    rows = []
    if model != CLASSICAL:
        scores = evaluate(classical, BASES[CLASSICAL], data, run)
        rows.append({"model": CLASSICAL, "knob": "reference", "value": "classical", "seeds": 1,
                     **DETERMINISTIC, **scores, "train_s": classical["fit_s"],
                     "peak_train_mb": classical["peak_train_mb"]})
    rows.append({"model": "average", "knob": "reference", "value": "average", "seeds": 1, **DETERMINISTIC,
                 **average_reference(data, run, classical)})
    return rows


SETTING_FIELDS = tuple(f.name for f in fields(Setting))
