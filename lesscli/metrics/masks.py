"""Metric primitives on boolean masks in physical units (numpy/scipy only, never torch).

Masks are (D, H, W) = (z, y, x) boolean arrays on a grid with ``origin_mm`` (z, y, x of voxel
[0, 0, 0]'s centre) and ``spacing_mm`` (dz, dy, dx), as in :mod:`lesscli.io.labels`. A 2D mask is
a depth-1 volume.

Undefined values are ``None`` (written as JSON null), never 0 or a "perfect" score; each function
states its rule for empty masks. F1 is ``2 TP / (2 TP + FP + FN)``: the harmonic mean of precision and
recall where both are defined, and 0 when exactly one mask is empty (a miss or a pure false alarm is a
real error). The size of an empty mask is 0 mm^3, so size errors are always defined; a centroid or a
diameter of nothing does not exist, so errors that need one are undefined and are counted as such by
the summaries (``*_n``).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

DIAMETER_POINTS = ("centres", "corners")
# Corner offsets of a pixel in units of (dy, dx) for the "corners" variant.
_CORNERS = np.array([[-0.5, -0.5], [-0.5, 0.5], [0.5, -0.5], [0.5, 0.5]])


def confusion(pred: np.ndarray, truth: np.ndarray) -> tuple[int, int, int]:
    """Voxel counts (TP, FP, FN) of two boolean masks of the same shape."""
    pred, truth = np.asarray(pred, bool), np.asarray(truth, bool)
    if pred.shape != truth.shape:
        raise ValueError(f"mask shapes differ: prediction {pred.shape}, truth {truth.shape}")
    n_pred, n_true = int(np.count_nonzero(pred)), int(np.count_nonzero(truth))
    tp = int(np.count_nonzero(pred & truth))
    return tp, n_pred - tp, n_true - tp


def precision_from(tp: int, fp: int, fn: int) -> float | None:
    """TP / (TP + FP); None when the prediction is empty."""
    return tp / (tp + fp) if tp + fp else None


def recall_from(tp: int, fp: int, fn: int) -> float | None:
    """TP / (TP + FN); None when the truth is empty."""
    return tp / (tp + fn) if tp + fn else None


def f1_from(tp: int, fp: int, fn: int) -> float | None:
    """2 TP / (2 TP + FP + FN); None when both masks are empty."""
    denom = 2 * tp + fp + fn
    return 2 * tp / denom if denom else None


def dice(a: np.ndarray, b: np.ndarray) -> float | None:
    """Dice overlap (= F1) of two boolean masks; None when both are empty. Symmetric."""
    return f1_from(*confusion(a, b))


def arse(n_pred: float, n_true: float) -> float | None:
    """Absolute relative size error | |p| - |y| | / (0.5 (|p| + |y|)) in [0, 2]; None if both are 0."""
    total = n_pred + n_true
    return abs(n_pred - n_true) / (0.5 * total) if total else None


def size_mm(mask: np.ndarray, cell_mm: float) -> float:
    """Total size of a mask: voxel count times the cell size (mm^3 per voxel or mm^2 per pixel)."""
    return float(np.count_nonzero(mask)) * float(cell_mm)


def centroid_mm(mask: np.ndarray, origin_mm: np.ndarray, spacing_mm: np.ndarray) -> np.ndarray | None:
    """Centre of mass of a (D, H, W) mask in the phantom frame, (3,) z, y, x mm; None if empty.

    Every voxel weighs the same (voxel centres are averaged); computed from the per-axis
    projections in float64, so no index arrays are built.
    """
    mask = np.asarray(mask, bool)
    count = int(np.count_nonzero(mask))
    if count == 0:
        return None
    means = []
    for axis in range(3):
        others = tuple(a for a in range(3) if a != axis)
        profile = mask.sum(axis=others, dtype=np.float64)
        means.append(float(profile @ np.arange(mask.shape[axis], dtype=np.float64)) / count)
    return np.asarray(origin_mm, np.float64) + np.asarray(spacing_mm, np.float64) * np.array(means)


def distance_mm(a: np.ndarray | None, b: np.ndarray | None) -> float | None:
    """Euclidean distance of two points in mm; None if either is None. Symmetric."""
    if a is None or b is None:
        return None
    return float(np.linalg.norm(np.asarray(a, np.float64) - np.asarray(b, np.float64)))


def abs_diff(a: float | None, b: float | None) -> float | None:
    """|a - b|; None if either is None."""
    return None if a is None or b is None else abs(float(a) - float(b))


def _hull_diameter(points: np.ndarray) -> float:
    """Largest distance between two of ``points`` (n, 2), through their convex hull."""
    points = np.unique(points, axis=0)
    if len(points) > 3:
        try:
            points = points[ConvexHull(points).vertices]
        except QhullError:  # all points on one line: the extreme points in lexicographic order
            points = points[[0, -1]]
    diff = points[:, None, :] - points[None, :, :]
    return float(np.sqrt((diff**2).sum(axis=-1)).max())


def _slice_points(rows: np.ndarray, left: np.ndarray, right: np.ndarray, dy: float, dx: float,
                  points: str) -> np.ndarray:
    """Candidate hull points of one slice from each occupied row's leftmost/rightmost pixel, mm."""
    idx = np.concatenate([np.stack([rows, left], 1), np.stack([rows, right], 1)]).astype(np.float64)
    if points == "corners":
        idx = (idx[:, None, :] + _CORNERS[None]).reshape(-1, 2)
    return idx * np.array([dy, dx])


def slice_diameters_mm(mask: np.ndarray, spacing_mm: np.ndarray, points: str = "centres") -> np.ndarray:
    """Per-slice inclusion diameter of a (D, H, W) mask, (D,) mm, NaN for empty slices.

    The diameter of a slice is the largest in-plane Euclidean distance between two of its pixels.
    ``points="centres"`` (default, the paper's "distance between two pixels") measures between
    pixel centres, so a single pixel has diameter 0; ``points="corners"`` measures between pixel
    corners (a single pixel spans its diagonal). Only each row's leftmost and rightmost pixels can
    be convex-hull vertices, so the hull is built from at most 2 H (centres) or 8 H (corners)
    points per slice and the largest distance is taken among its vertices: no O(n^2) all-pairs
    distances over the pixels.
    """
    if points not in DIAMETER_POINTS:
        raise ValueError(f"points must be one of {DIAMETER_POINTS}, got {points!r}")
    mask = np.asarray(mask, bool)
    depth, _, width = mask.shape
    dy, dx = (float(s) for s in np.asarray(spacing_mm, np.float64)[1:])
    occupied = mask.any(axis=2)
    left = mask.argmax(axis=2)
    right = width - 1 - mask[:, :, ::-1].argmax(axis=2)
    out = np.full(depth, np.nan)
    for k in np.flatnonzero(occupied.any(axis=1)):
        rows = np.flatnonzero(occupied[k])
        out[k] = _hull_diameter(_slice_points(rows, left[k, rows], right[k, rows], dy, dx, points))
    return out


def diameter_mm(mask: np.ndarray, spacing_mm: np.ndarray, points: str = "centres") -> float | None:
    """Inclusion diameter: the largest per-slice diameter over all slices, mm; None if the mask is empty.

    Empty slices are ignored (not averaged in as 0).
    """
    per_slice = slice_diameters_mm(mask, spacing_mm, points)
    return float(np.nanmax(per_slice)) if np.isfinite(per_slice).any() else None


def all_pairs_diameter_mm(mask: np.ndarray, spacing_mm: np.ndarray) -> float | None:
    """Reference O(n^2) version of :func:`diameter_mm` (pixel centres), for tests and benchmarks."""
    from scipy.spatial.distance import pdist

    best = None
    dy, dx = (float(s) for s in np.asarray(spacing_mm, np.float64)[1:])
    for sl in np.asarray(mask, bool):
        pts = np.argwhere(sl) * np.array([dy, dx])
        if len(pts):
            d = float(pdist(pts).max()) if len(pts) > 1 else 0.0
            best = d if best is None else max(best, d)
    return best
