"""Per-scan metric rows for prediction sets and label-volume pairs.

Each row carries identity keys (``row``, ``file``, ``set``, ``model``, ``seed``, ``dim``, ``cls``,
``threshold``, ``scan``, ``insert``, ``orientation``, ``steps``) and the metric keys of
:mod:`lesscli.metrics.volume`. Scans without a stored truth cannot be scored and are skipped
(:func:`count_unscored` tells how many).
"""

from __future__ import annotations

import hashlib

import numpy as np

from lesscli.errors import DataError
from lesscli.io.labels import LabelVolume
from lesscli.io.predictions import PredictionSet, ScanPrediction, labels_from_probs, whole_scans
from lesscli.metrics.baseline import AverageBaseline, score_baseline
from lesscli.metrics.volume import score_labels

# Meta keys copied into every row (the prediction file's description of itself).
META_KEYS = ("set", "model", "seed", "dim")
BASELINE_MODEL = "average"  # the model name of the average-prediction baseline rows
GRID_TOL_MM = 1e-4  # two grids match when origins and spacings agree to this many mm


def _identity(preds: PredictionSet, name: str, cls: str, threshold: float | None, extra_keys=()) -> dict:
    meta = preds.meta
    ident = {"row": "scan", "file": name, **{k: meta.get(k) for k in META_KEYS}, "cls": cls,
             "threshold": meta.get("threshold") if threshold is None else threshold}
    for key in extra_keys:
        value = meta.get(key)
        ident[key] = value if value is None or isinstance(value, (str, int, float, bool)) else str(value)
    return ident


def _scan_ident(i: int, scan: ScanPrediction) -> dict:
    return {"scan": i, "insert": scan.insert, "orientation": scan.orientation, "steps": scan.steps}


def scan_labels(scan: ScanPrediction, threshold: float | None = None) -> np.ndarray:
    """Predicted codes (D, H, W): the stored labels, or re-labelled from the probabilities at
    ``threshold``."""
    return scan.label if threshold is None else labels_from_probs(scan.probs, threshold)


def score_prediction_set(preds: PredictionSet, name: str = "", cls: str = "inclusion",
                         threshold: float | None = None, points: str = "centres",
                         extra_keys: tuple[str, ...] = ()) -> list[dict]:
    """One row per scan with truth, scored on its whole sequence: a file of ``image predict --steps``
    holds several prefixes of each scan, and only the last (the whole scan) is scored (``scan`` is the
    scan's number, not the prediction's).

    Args:
        preds: a loaded ``less.pred/1`` set.
        name: the file name written in the ``file`` key.
        cls: ``"inclusion"`` or ``"pillar"``.
        threshold: re-label from the probabilities with :func:`labels_from_probs` (None: stored labels).
        points: ``"centres"`` or ``"corners"`` for the diameter.
        extra_keys: further scalar ``meta`` keys copied into each row (e.g. for grouping).
    """
    ident = _identity(preds, name, cls, threshold, extra_keys)
    rows = []
    for i, scan in enumerate(whole_predictions(preds)):
        if scan.truth is None:
            continue
        labels = scan_labels(scan, threshold)
        if labels.shape != scan.truth.shape:
            raise DataError(f"{name or 'predictions'}: scan {i} has prediction {labels.shape} but truth "
                            f"{scan.truth.shape}; both must be on the same (D, H, W) grid")
        metrics = score_labels(labels, scan.truth, scan.origin_mm, scan.spacing_mm, cls, points)
        rows.append({**ident, **_scan_ident(i, scan), **metrics})
    return rows


def whole_predictions(preds: PredictionSet) -> list[ScanPrediction]:
    """The prediction of each scan's whole sequence, in scan order (prefixes left out;
    io.predictions.whole_scans)."""
    return [preds.scans[i] for i in whole_scans(preds.scans)]


def count_prefixes(preds: PredictionSet) -> int:
    """Predictions of prefixes (``image predict --steps`` / ``--every``) that are not a whole scan."""
    return len(preds.scans) - len(whole_scans(preds.scans))


def count_unscored(preds: PredictionSet) -> int:
    """Scans without a stored truth."""
    return sum(scan.truth is None for scan in whole_predictions(preds))


def truth_fingerprint(preds: PredictionSet) -> str:
    """Hash of all truths and geometries: prediction files of the same test set share it."""
    h = hashlib.sha1()
    for scan in whole_predictions(preds):
        if scan.truth is not None:
            for arr in (np.asarray(scan.truth.shape, np.int64), scan.origin_mm, scan.spacing_mm, scan.truth):
                h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def score_baseline_set(preds: PredictionSet, baseline: AverageBaseline, name: str = "",
                       cls: str = "inclusion", points: str = "centres", source: str = "") -> list[dict]:
    """Rows of the average-prediction baseline (``model`` is :data:`BASELINE_MODEL`) on the truths of
    ``preds``."""
    ident = {"row": "scan", "file": name, "set": preds.meta.get("set"), "model": BASELINE_MODEL, "seed": None,
             "dim": preds.meta.get("dim"), "cls": cls, "threshold": None, "baseline_from": source}
    return [{**ident, **_scan_ident(i, scan),
             **score_baseline(baseline, scan.truth, scan.origin_mm, scan.spacing_mm, cls, points)}
            for i, scan in enumerate(whole_predictions(preds)) if scan.truth is not None]


def check_same_grid(pred: LabelVolume, truth: LabelVolume, pred_name: str, truth_name: str) -> None:
    """Raise DataError naming both files when two label volumes are not on the same grid."""
    if pred.shape != truth.shape:
        raise DataError(f"{pred_name}: grid {pred.shape} does not match {truth_name} {truth.shape}; "
                         "resample one onto the other first")
    for what, a, b in (("origin", pred.origin_mm, truth.origin_mm),
                       ("spacing", pred.spacing_mm, truth.spacing_mm)):
        if not np.allclose(a, b, rtol=0.0, atol=GRID_TOL_MM):
            raise DataError(f"{pred_name}: voxel {what} {np.round(a, 4).tolist()} mm does not match "
                             f"{truth_name} {np.round(b, 4).tolist()} mm; resample one onto the other first")


def score_label_pair(pred: LabelVolume, truth: LabelVolume, pred_name: str = "", truth_name: str = "",
                     cls: str = "inclusion", points: str = "centres") -> dict:
    """One row for a predicted label volume against a reference on the same grid (e.g. NIfTI files)."""
    check_same_grid(pred, truth, pred_name, truth_name)
    ident = {"row": "scan", "file": pred_name, "truth": truth_name, "set": None, "model": None, "seed": None,
             "dim": 3 if pred.shape[0] > 1 else 2, "cls": cls, "threshold": None}
    return {**ident, **score_labels(pred.data, truth.data, truth.origin_mm, truth.spacing_mm, cls, points)}
