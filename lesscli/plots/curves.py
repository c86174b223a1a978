"""Training curves of one or more runs from their ``<stem>.log.jsonl`` (``less plot log``).

One panel per quantity some log holds, runs overlaid in one colour each (training solid, validation
dashed):

- loss: ``train_loss`` and ``val_loss`` per epoch (log scale when they span more than a factor 10);
- force error vs the mean baseline: ``val_loss / val_baseline_mse`` (pretrain with ``--val``; below 1
  the representation predicts forces better than the training mean);
- imaging F1: ``val_score``, the validation inclusion F1 of ``image fit`` selecting by F1.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lesscli.errors import DataError
from lesscli.io.records import read_jsonl
from lesscli.plots.render import agg_figure
from lesscli.plots.sweeps import save_figure

PANEL_IN = (5.0, 3.6)


@dataclass
class Run:
    """One run's epoch records and the name it is drawn under."""

    label: str
    path: str
    records: list[dict]

    def series(self, key: str) -> tuple[np.ndarray, np.ndarray]:
        """(epochs, values) of the records that hold a number under ``key``."""
        rows = [r for r in self.records if isinstance(r.get(key), (int, float))
                and not isinstance(r[key], bool)]
        return np.array([r["epoch"] for r in rows], float), np.array([r[key] for r in rows], float)

    def ratio(self) -> tuple[np.ndarray, np.ndarray]:
        """(epochs, val_loss / val_baseline_mse) where both are there and the baseline is positive."""
        rows = [r for r in self.records if r.get("val_loss") is not None
                and (r.get("val_baseline_mse") or 0) > 0]
        return (np.array([r["epoch"] for r in rows], float),
                np.array([r["val_loss"] / r["val_baseline_mse"] for r in rows], float))


def run_label(path: str) -> str:
    """``runs/s0/rep.log.jsonl`` -> ``runs/s0/rep``."""
    return path.removesuffix(".jsonl").removesuffix(".log")


def load_run(path: str, label: str | None = None) -> Run:
    """A training log -> Run; DataError naming the file when it holds no epoch records."""
    records = [r for r in read_jsonl(path) if isinstance(r, dict) and "epoch" in r]
    if not records or not all(isinstance(r.get("train_loss"), (int, float)) for r in records):
        raise DataError(f"{path}: not a training log (expected JSON lines with 'epoch' and 'train_loss', "
                        "as written beside a checkpoint by pretrain / image fit)")
    return Run(label or run_label(path), path, sorted(records, key=lambda r: r["epoch"]))


def summary(run: Run) -> dict:
    """One record per run: epochs, last training loss, best validation values."""
    _, val = run.series("val_loss")
    _, f1 = run.series("val_score")
    _, ratio = run.ratio()
    best = lambda a, f: float(f(a)) if len(a) else None
    return {"run": run.label, "file": run.path, "epochs": int(run.records[-1]["epoch"]),
            "last_train_loss": float(run.records[-1]["train_loss"]), "best_val_loss": best(val, np.min),
            "best_val_f1": best(f1, np.max), "best_force_ratio": best(ratio, np.min)}


def curves_figure(runs: Sequence[Run], path: str, title: str = "") -> None:
    """Write the figure of the runs' curves (see the module docstring) to ``path`` atomically: PNG, or PDF /
    SVG by the path's extension."""
    panels = [("loss",
               lambda r: [(r.series("train_loss"), "-", "train"), (r.series("val_loss"), "--", "val")])]
    if any(len(r.ratio()[0]) for r in runs):
        panels.append(("force error / mean baseline (val)", lambda r: [(r.ratio(), "--", "val")]))
    if any(len(r.series("val_score")[0]) for r in runs):
        panels.append(("imaging F1, inclusion (val)", lambda r: [(r.series("val_score"), "--", "val")]))
    fig = agg_figure((PANEL_IN[0] * len(panels), PANEL_IN[1]))
    axes = np.atleast_1d(fig.subplots(1, len(panels)))
    colours = [f"C{i % 10}" for i in range(len(runs))]
    for ax, (name, lines) in zip(axes, panels):
        values = []
        for run, colour in zip(runs, colours):
            for (x, y), style, part in lines(run):
                if len(x):
                    ax.plot(x, y, style, color=colour, marker="." if len(x) < 30 else None,
                            label=f"{run.label} ({part})")
                    values += [v for v in y if math.isfinite(v)]
        if name == "loss" and values and min(values) > 0 and max(values) > 10 * min(values):
            ax.set_yscale("log")
        if name.startswith("force"):
            ax.axhline(1.0, color="0.5", lw=1, ls=":", label="mean baseline")
        ax.set_title(name, fontsize="medium")
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="x-small")
    if title:
        fig.suptitle(title)
    save_figure(fig, path)


def plot_logs(paths: Sequence[str], output: str, labels: Sequence[str] = ()) -> list[dict]:
    """Load the logs (``labels`` name them in order; default: the path without ``.log.jsonl``), draw
    ``output``, return one summary record per run."""
    if labels and len(labels) != len(paths):
        raise DataError(f"{len(labels)} labels for {len(paths)} logs; give one --label per log or none")
    runs = [load_run(p, labels[i] if labels else None) for i, p in enumerate(paths)]
    curves_figure(runs, output)
    return [summary(r) for r in runs]
