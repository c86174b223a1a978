"""The "average prediction" baseline: always predict the training set's mean diameter and centroid.

Scored as geometry (diameter and centroid errors) and as a mask: the mean sphere (2D: the mean disc on
the truth's largest slice) painted on the truth's grid, so its F1 stands beside a learned imager's.

Built from training label volumes (one per scan that has one, so an insert scanned more often
weighs more, as in the test set). Volumes without the class are skipped and counted. The 2D
baseline uses each volume's slice with the largest true area and predicts the mean in-plane
(y, x) centroid and mean slice diameter.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from lesscli.io.labels import LabelVolume
from lesscli.metrics import masks as m
from lesscli.metrics.volume import class_code, largest_slice


@dataclass(frozen=True)
class AverageBaseline:
    """Mean training-set geometry of one class.

    Attributes:
        diameter_mm_3d: mean inclusion diameter (max over slices), mm.
        centroid_mm_3d: (3,) mean z, y, x centroid in the phantom frame, mm.
        diameter_mm_2d: mean diameter on the largest true slice, mm.
        centroid_mm_2d: (2,) mean y, x centroid on that slice, mm.
        n_volumes: volumes averaged; n_empty: volumes skipped because they hold no voxel of the class.
    """

    diameter_mm_3d: float
    centroid_mm_3d: np.ndarray
    diameter_mm_2d: float
    centroid_mm_2d: np.ndarray
    n_volumes: int
    n_empty: int


def _geometry(vol: LabelVolume, code: int, points: str) -> tuple[float, np.ndarray, float, np.ndarray] | None:
    mask = vol.data == code
    k = largest_slice(mask)
    if k is None:
        return None
    c3 = m.centroid_mm(mask, vol.origin_mm, vol.spacing_mm)
    c2 = m.centroid_mm(mask[k:k + 1], vol.origin_mm, vol.spacing_mm)[1:]
    return (m.diameter_mm(mask, vol.spacing_mm, points), c3,
            m.diameter_mm(mask[k:k + 1], vol.spacing_mm, points), c2)


def average_baseline(volumes: Iterable[LabelVolume], cls: str = "inclusion",
                     points: str = "centres") -> AverageBaseline:
    """Mean diameter and centroid of ``cls`` over training label volumes.

    Raises:
        ValueError: no volume holds the class.
    """
    code = class_code(cls)
    found, n_empty = [], 0
    for vol in volumes:
        geo = _geometry(vol, code, points)
        if geo is None:
            n_empty += 1
        else:
            found.append(geo)
    if not found:
        raise ValueError(f"no training volume contains the class '{cls}' ({n_empty} empty)")
    d3, c3, d2, c2 = zip(*found)
    return AverageBaseline(float(np.mean(d3)), np.mean(c3, axis=0), float(np.mean(d2)), np.mean(c2, axis=0),
                           len(found), n_empty)


def score_baseline(baseline: AverageBaseline, truth_labels: np.ndarray, origin_mm: np.ndarray,
                   spacing_mm: np.ndarray, cls: str = "inclusion", points: str = "centres") -> dict:
    """Diameter and centroid errors of the average prediction against one (D, H, W) truth volume.

    Returns the keys ``diameter_error_mm_S``, ``com_error_mm_S``, ``diameter_true_mm_S``,
    ``diameter_pred_mm_S`` and the mask scores ``tp_S``, ``fp_S``, ``fn_S``, ``f1_S`` for S in 3d
    (depth > 1 only) and 2d; None where the truth has no voxel of the class (3D masks are still
    scored: the sphere is then all false positives).
    """
    mask = np.asarray(truth_labels) == class_code(cls)
    origin_mm, spacing_mm = np.asarray(origin_mm, np.float64), np.asarray(spacing_mm, np.float64)
    row: dict = {}
    k = largest_slice(mask)
    variants = [("3d", mask, baseline.diameter_mm_3d, baseline.centroid_mm_3d, slice(0, 3))] \
        if mask.shape[0] > 1 else []
    if k is not None:
        variants.append(("2d", mask[k:k + 1], baseline.diameter_mm_2d, baseline.centroid_mm_2d, slice(1, 3)))
    else:
        row.update({f"{key}_2d": None for key in ("diameter_true_mm", "diameter_error_mm", "com_error_mm",
                                                   "tp", "fp", "fn", "f1")})
        row["diameter_pred_mm_2d"] = baseline.diameter_mm_2d
    for suffix, sub, d_pred, c_pred, axes in variants:
        d_true = m.diameter_mm(sub, spacing_mm, points)
        c_true = m.centroid_mm(sub, origin_mm, spacing_mm)
        sub_origin = origin_mm + np.array([spacing_mm[0] * (k or 0) if suffix == "2d" else 0.0, 0.0, 0.0])
        centre = np.asarray(c_pred) if suffix == "3d" else np.array([sub_origin[0], *c_pred])
        tp, fp, fn = m.confusion(ball_mask(centre, d_pred, sub.shape, sub_origin, spacing_mm), sub)
        row.update({f"diameter_true_mm_{suffix}": d_true, f"diameter_pred_mm_{suffix}": d_pred,
                    f"diameter_error_mm_{suffix}": m.abs_diff(d_pred, d_true),
                    f"com_error_mm_{suffix}": m.distance_mm(c_pred,
                                                            None if c_true is None else c_true[axes]),
                    f"tp_{suffix}": tp, f"fp_{suffix}": fp, f"fn_{suffix}": fn,
                    f"f1_{suffix}": m.f1_from(tp, fp, fn)})
    return row


def ball_mask(centre_mm: np.ndarray, diameter_mm: float, shape: tuple, origin_mm: np.ndarray,
              spacing_mm: np.ndarray) -> np.ndarray:
    """(D, H, W) bool: voxels whose centres lie within the ball (z, y, x centre, mm) of ``diameter_mm``."""
    axes = [origin_mm[a] + spacing_mm[a] * np.arange(shape[a]) - centre_mm[a] for a in range(3)]
    d2 = axes[0][:, None, None] ** 2 + axes[1][None, :, None] ** 2 + axes[2][None, None, :] ** 2
    return d2 <= (diameter_mm / 2.0) ** 2
