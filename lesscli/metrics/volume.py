"""Score one predicted label volume against its truth: 3D metrics and the 2D ones on one slice.

3D metrics use the full (D, H, W) volume. 2D metrics use, per volume, the slice with the largest
true area of the class (lowest slice index on ties), following the paper; when the truth has no
voxel of the class the slice, and every 2D metric, is undefined (None). A depth-1 volume (a 2D
prediction at its slice) gets only the 2D metrics.

Row keys (``S`` is ``3d`` or ``2d``; sizes are ``volume_*_mm3`` in 3D and ``area_*_mm2`` in 2D):
``tp_S fp_S fn_S`` voxel counts, ``precision_S recall_S f1_S`` fractions in [0, 1],
``com_error_mm_S``, ``arse_S``, ``diameter_true_mm_S diameter_pred_mm_S diameter_error_mm_S``,
``truth_empty_S pred_empty_S``; 2D adds ``slice_2d`` (index along z) and ``slice_z_mm``.
"""

from __future__ import annotations

import numpy as np

from lesscli.io.labels import INCLUSION, PILLAR
from lesscli.metrics import masks as m

# Classes that can be scored: name -> label code.
CLASSES: dict[str, int] = {"inclusion": INCLUSION, "pillar": PILLAR}

# Metrics averaged by the summaries (means over valid values, std with ddof=1, count of valid values).
METRICS_3D = ("f1_3d", "precision_3d", "recall_3d", "com_error_mm_3d", "arse_3d", "diameter_error_mm_3d",
              "diameter_true_mm_3d", "diameter_pred_mm_3d", "volume_error_mm3", "volume_true_mm3",
              "volume_pred_mm3")
METRICS_2D = ("f1_2d", "precision_2d", "recall_2d", "com_error_mm_2d", "arse_2d", "diameter_error_mm_2d",
              "diameter_true_mm_2d", "diameter_pred_mm_2d", "area_error_mm2", "area_true_mm2",
              "area_pred_mm2")
MICRO = ("f1_micro_3d", "precision_micro_3d", "recall_micro_3d",
         "f1_micro_2d", "precision_micro_2d", "recall_micro_2d")
METRIC_KEYS = METRICS_3D + METRICS_2D + MICRO


def class_code(cls: str) -> int:
    """Label code of a class name in :data:`CLASSES`."""
    if cls not in CLASSES:
        raise ValueError(f"unknown class {cls!r}; choose one of {', '.join(CLASSES)}")
    return CLASSES[cls]


def compare_masks(pred: np.ndarray, truth: np.ndarray, origin_mm: np.ndarray, spacing_mm: np.ndarray,
                  suffix: str, size_name: str, cell_mm: float, points: str = "centres") -> dict:
    """All metrics of two (D, H, W) boolean masks on one grid.

    Args:
        pred, truth: (D, H, W) bool.
        origin_mm, spacing_mm: (3,) z, y, x grid geometry, mm.
        suffix: key suffix, ``"3d"`` or ``"2d"``.
        size_name: ``"volume"`` (mm^3) or ``"area"`` (mm^2), with ``cell_mm`` the size of one cell.
        points: pixel ``"centres"`` or ``"corners"`` for the diameter (see :func:`masks.slice_diameters_mm`).

    Returns:
        dict of row keys (see the module docstring); undefined values are None.
    """
    tp, fp, fn = m.confusion(pred, truth)
    unit = "mm3" if size_name == "volume" else "mm2"
    true_size, pred_size = m.size_mm(truth, cell_mm), m.size_mm(pred, cell_mm)
    d_true, d_pred = m.diameter_mm(truth, spacing_mm, points), m.diameter_mm(pred, spacing_mm, points)
    return {
        f"tp_{suffix}": tp, f"fp_{suffix}": fp, f"fn_{suffix}": fn,
        f"precision_{suffix}": m.precision_from(tp, fp, fn), f"recall_{suffix}": m.recall_from(tp, fp, fn),
        f"f1_{suffix}": m.f1_from(tp, fp, fn),
        f"com_error_mm_{suffix}": m.distance_mm(m.centroid_mm(pred, origin_mm, spacing_mm),
                                                m.centroid_mm(truth, origin_mm, spacing_mm)),
        f"arse_{suffix}": m.arse(tp + fp, tp + fn),
        f"diameter_true_mm_{suffix}": d_true, f"diameter_pred_mm_{suffix}": d_pred,
        f"diameter_error_mm_{suffix}": m.abs_diff(d_pred, d_true),
        f"{size_name}_true_{unit}": true_size, f"{size_name}_pred_{unit}": pred_size,
        f"{size_name}_error_{unit}": abs(pred_size - true_size),
        f"truth_empty_{suffix}": tp + fn == 0, f"pred_empty_{suffix}": tp + fp == 0,
    }


def largest_slice(truth: np.ndarray) -> int | None:
    """Index of the z slice with the most true voxels of a (D, H, W) mask (lowest on ties); None if empty."""
    areas = np.asarray(truth, bool).sum(axis=(1, 2))
    return int(areas.argmax()) if areas.any() else None


def _undefined_2d() -> dict:
    keys = [*METRICS_2D, "tp_2d", "fp_2d", "fn_2d", "slice_2d", "slice_z_mm"]
    return {**dict.fromkeys(keys), "truth_empty_2d": True, "pred_empty_2d": None}


def score_masks(pred: np.ndarray, truth: np.ndarray, origin_mm: np.ndarray, spacing_mm: np.ndarray,
                points: str = "centres") -> dict:
    """3D metrics (depth > 1 only) and 2D metrics on the largest true slice of two (D, H, W) masks."""
    pred, truth = np.asarray(pred, bool), np.asarray(truth, bool)
    if pred.shape != truth.shape or pred.ndim != 3:
        raise ValueError(f"prediction {pred.shape} and truth {truth.shape} must be the same (D, H, W) grid")
    origin_mm, spacing_mm = np.asarray(origin_mm, np.float64), np.asarray(spacing_mm, np.float64)
    row: dict = {}
    if pred.shape[0] > 1:
        row.update(compare_masks(pred, truth, origin_mm, spacing_mm, "3d", "volume",
                                 float(np.prod(spacing_mm)), points))
    k = largest_slice(truth)
    if k is None:
        row.update(_undefined_2d())
        return row
    origin_k = origin_mm + np.array([k * spacing_mm[0], 0.0, 0.0])
    row.update(compare_masks(pred[k:k + 1], truth[k:k + 1], origin_k, spacing_mm, "2d", "area",
                             float(spacing_mm[1] * spacing_mm[2]), points))
    row.update(slice_2d=k, slice_z_mm=float(origin_k[0]))
    return row


def score_labels(pred_labels: np.ndarray, truth_labels: np.ndarray, origin_mm: np.ndarray,
                 spacing_mm: np.ndarray, cls: str = "inclusion", points: str = "centres") -> dict:
    """:func:`score_masks` for one class of two (D, H, W) uint8 label volumes (codes 0..3)."""
    code = class_code(cls)
    return score_masks(np.asarray(pred_labels) == code, np.asarray(truth_labels) == code,
                       origin_mm, spacing_mm, points)
