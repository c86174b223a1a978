"""Figures of predictions: truth | prediction | uncertainty side by side, strips over time, and
truth | model A | model B ... for several imagers of the same scans.

Images are drawn in phantom-frame millimetres (x right, y up). 3D volumes show a top view (the
highest class code along depth, i.e. inclusion over pillar over insert; entropy averaged over
depth) and slices through the inclusion and below it (where the pillar is). A prediction's colours
fade towards white where it is uncertain (:meth:`ScanPrediction.confidence`: a near-uniform guess,
such as an untrained model's, is almost white), and black dots mark where the pad touched (the
pad's centre at the steps in contact, stored with the prediction). Figures are drawn with matplotlib's Agg
canvas created inside each function (no global backend state).
"""

from __future__ import annotations

import math

import numpy as np

from lesscli.io.labels import CLASS_NAMES, INCLUSION
from lesscli.io.predictions import ScanPrediction, scan_numbers
from lesscli.plots.palette import CLASS_RGBA

PANEL_IN = 3.0          # panel side, inches
DPI = 100


def agg_figure(figsize_in: tuple[float, float]):
    """A matplotlib Figure on its own Agg canvas (no pyplot, no global backend state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize_in, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _canvas(rows: int, cols: int):
    fig = agg_figure((PANEL_IN * cols + 1.2, PANEL_IN * rows + 0.9))
    axes = np.asarray(fig.subplots(rows, cols, squeeze=False))
    return fig, axes


def extent_mm(pred: ScanPrediction) -> list[float]:
    """imshow extent [x_min, x_max, y_min, y_max] of voxel edges, mm."""
    (_, y0, x0), (_, dy, dx) = pred.origin_mm, pred.spacing_mm
    h, w = pred.label.shape[1:]
    return [x0 - dx / 2, x0 + (w - 0.5) * dx, y0 - dy / 2, y0 + (h - 0.5) * dy]


def views(pred: ScanPrediction) -> list[tuple[str, slice | int]]:
    """(name, depth selector) rows: the image for 2D; top view and two slices for 3D."""
    depth = pred.label.shape[0]
    if depth == 1:
        return [("", 0)]
    ref = pred.truth if pred.truth is not None else pred.label
    area = (ref == INCLUSION).sum(axis=(1, 2))
    k = int(area.argmax()) if area.any() else depth // 2
    below = max(0, k - max(1, k // 2))           # slice index grows upward (z = origin + k dz)
    z = lambda i: pred.origin_mm[0] + i * pred.spacing_mm[0]
    return [("top view", slice(None)), (f"slice z = {z(k):.1f} mm", k),
            (f"slice z = {z(below):.1f} mm", below)]


def _codes(volume: np.ndarray, sel) -> np.ndarray:
    return volume.max(axis=0) if isinstance(sel, slice) else volume[sel]


def _entropy(pred: ScanPrediction, sel) -> np.ndarray:
    ent = pred.entropy.astype(np.float32)
    return ent.mean(axis=0) if isinstance(sel, slice) else ent[sel]


def _draw_labels(ax, codes: np.ndarray, ext: list[float], confidence: np.ndarray | None = None):
    """Label codes in the class colours; with ``confidence`` (same shape, 0..1) each pixel's colour is
    blended towards white by how uncertain it is, so a near-uniform guess shows faintly, not as a
    confident image."""
    rgb = CLASS_RGBA[np.asarray(codes, np.int64)][..., :3]
    if confidence is not None:
        rgb = 1.0 - np.clip(confidence, 0.0, 1.0)[..., None] * (1.0 - rgb)
    ax.imshow(rgb, origin="lower", extent=ext, interpolation="nearest")


def _shown_confidence(pred: ScanPrediction, sel) -> np.ndarray:
    """The confidence (ScanPrediction.confidence) of the voxel each pixel of the view shows: in a top
    view the topmost voxel of the class drawn there (the highest code along depth)."""
    conf = pred.confidence()
    if not isinstance(sel, slice):
        return conf[sel]
    top = pred.label.max(axis=0)
    k = np.argmax(pred.label == top[None], axis=0)
    return np.take_along_axis(conf, k[None], axis=0)[0]


TOUCH_STYLE = {"s": 9, "c": "black", "marker": ".", "linewidths": 0, "alpha": 0.7}


def _draw_touches(ax, pred: ScanPrediction, ext: list[float]) -> None:
    """Where the pad touched (its centre at the steps in contact), as small dots over the image."""
    xy = pred.touch_xy_mm
    if xy is None or not len(xy):
        return
    ax.scatter(xy[:, 0], xy[:, 1], label="pad touched", **TOUCH_STYLE)
    ax.set_xlim(ext[0], ext[1])
    ax.set_ylim(ext[2], ext[3])


def _draw_prediction(ax, pred: ScanPrediction, sel, ext: list[float]) -> None:
    _draw_labels(ax, _codes(pred.label, sel), ext, _shown_confidence(pred, sel))
    _draw_touches(ax, pred, ext)


def _draw_entropy(ax, ent: np.ndarray, ext: list[float], n_classes: int):
    return ax.imshow(ent, cmap="magma", vmin=0.0, vmax=math.log(n_classes), origin="lower", extent=ext,
                     interpolation="nearest")


def _legend(fig, touches: bool = False) -> None:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [Patch(facecolor=CLASS_RGBA[c], edgecolor="black", label=name) for c,
               name in enumerate(CLASS_NAMES)]
    handles.append(Patch(facecolor=tuple(1 - 0.25 * (1 - CLASS_RGBA[INCLUSION][:3])), edgecolor="black",
                         label="faint: uncertain"))
    if touches:
        handles.append(Line2D([], [], ls="", marker=".", color="black", label="pad touched"))
    fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), frameon=False)


def _touched(*preds: ScanPrediction) -> bool:
    return any(p.touch_xy_mm is not None and len(p.touch_xy_mm) for p in preds)


def _label_axes(ax, row: int, col: int, rows: int) -> None:
    if row == rows - 1:
        ax.set_xlabel("x (mm)")
    if col == 0:
        ax.set_ylabel("y (mm)")


def _blank(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)
    ax.set_xticks([])
    ax.set_yticks([])


def scan_figure(pred: ScanPrediction, path: str, title: str = "") -> str:
    """Truth | prediction | uncertainty (entropy, nats) for one prediction; writes a PNG at ``path``."""
    rows = views(pred)
    fig, axes = _canvas(len(rows), 3)
    ext, n_classes = extent_mm(pred), pred.probs.shape[0]
    image = None
    for r, (name, sel) in enumerate(rows):
        if pred.truth is not None:
            _draw_labels(axes[r, 0], _codes(pred.truth, sel), ext)
        else:
            _blank(axes[r, 0], "no truth")
        _draw_prediction(axes[r, 1], pred, sel, ext)
        image = _draw_entropy(axes[r, 2], _entropy(pred, sel), ext, n_classes)
        _draw_touches(axes[r, 2], pred, ext)
        for c, head in enumerate(("truth", "prediction", "uncertainty")):
            axes[r, c].set_title(f"{head}{' - ' + name if name else ''}", fontsize=9)
            _label_axes(axes[r, c], r, c, len(rows))
    fig.colorbar(image, ax=axes[:, 2].tolist(), label="entropy (nats)")
    _legend(fig, _touched(pred))
    fig.suptitle(title)
    fig.savefig(path, format="png")
    return path


def strip_figure(preds: list[ScanPrediction], path: str, title: str = "") -> str:
    """The image developing over time: one column per prefix, rows prediction and uncertainty."""
    preds = sorted(preds, key=lambda p: p.steps)
    has_truth = preds[-1].truth is not None
    cols = len(preds) + int(has_truth)
    fig, axes = _canvas(2, cols)
    ext, n_classes = extent_mm(preds[-1]), preds[-1].probs.shape[0]
    top = views(preds[-1])[0][1]
    if has_truth:
        _draw_labels(axes[0, 0], _codes(preds[-1].truth, top), ext)
        axes[0, 0].set_title("truth", fontsize=9)
        axes[1, 0].set_axis_off()
    image = None
    for j, p in enumerate(preds, start=int(has_truth)):
        _draw_prediction(axes[0, j], p, top, ext)
        image = _draw_entropy(axes[1, j], _entropy(p, top), ext, n_classes)
        _draw_touches(axes[1, j], p, ext)
        axes[0, j].set_title(f"{p.steps} steps", fontsize=9)
        axes[1, j].set_title(f"uncertainty, mean {float(p.entropy.mean()):.2f} nats", fontsize=8)
    for r in range(2):
        for c in range(int(has_truth and r == 1), cols):
            _label_axes(axes[r, c], r, c, 2)
    fig.colorbar(image, ax=axes[1, :].tolist(), label="entropy (nats)")
    _legend(fig, _touched(*preds))
    fig.suptitle(title)
    fig.savefig(path, format="png")
    return path


def compare_figure(preds: list[ScanPrediction], names: list[str], path: str, title: str = "") -> str:
    """Truth | one prediction per model for the same scan on the same grid; writes a PNG at ``path``.

    Args:
        preds: the predictions of one scan by each model (the truth is taken from the first).
        names: column titles, one per prediction (e.g. the models).
    """
    rows = views(preds[0])
    fig, axes = _canvas(len(rows), 1 + len(preds))
    ext, truth = extent_mm(preds[0]), preds[0].truth
    for r, (name, sel) in enumerate(rows):
        if truth is not None:
            _draw_labels(axes[r, 0], _codes(truth, sel), ext)
        else:
            _blank(axes[r, 0], "no truth")
        for c, pred in enumerate(preds, start=1):
            _draw_prediction(axes[r, c], pred, sel, ext)
        for c, head in enumerate(("truth", *names)):
            axes[r, c].set_title(f"{head}{' - ' + name if name else ''}", fontsize=9)
            _label_axes(axes[r, c], r, c, len(rows))
    _legend(fig, _touched(*preds))
    fig.suptitle(title)
    fig.savefig(path, format="png")
    return path


def group_scans(preds: list[ScanPrediction]) -> list[list[int]]:
    """Indices of the predictions of each scan (its prefixes in order; :func:`scan_numbers`)."""
    groups: list[list[int]] = []
    for i, s in enumerate(scan_numbers(preds)):
        if s == len(groups):
            groups.append([])
        groups[s].append(i)
    return groups
