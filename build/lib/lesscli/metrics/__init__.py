"""Imaging metrics in millimetres, as the paper defines them (numpy/scipy only, never torch).

Python API reused by other commands:

- :func:`dice`, :func:`confusion`, :func:`centroid_mm`, :func:`diameter_mm`: primitives on masks;
- :func:`score_labels` / :func:`score_masks`: one volume -> a dict of 3D and 2D metrics;
- :func:`score_prediction_set`: a ``less.pred/1`` set -> one row per scan;
- :func:`summarise`: rows -> mean, std (ddof=1) and count of valid values per group;
- :func:`average_baseline` / :func:`score_baseline`: the training-set mean diameter and centroid.

Undefined values are None (JSON null) and are counted, never turned into 0 or a perfect score;
the rule per metric is in :mod:`lesscli.metrics.masks`.
"""

from lesscli.metrics.baseline import AverageBaseline, average_baseline, score_baseline
from lesscli.metrics.masks import (
    arse,
    centroid_mm,
    confusion,
    diameter_mm,
    dice,
    f1_from,
    precision_from,
    recall_from,
    slice_diameters_mm,
)
from lesscli.metrics.score import (
    count_unscored,
    score_baseline_set,
    score_label_pair,
    score_prediction_set,
    truth_fingerprint,
)
from lesscli.metrics.summary import mean_std, summarise
from lesscli.metrics.volume import CLASSES, METRIC_KEYS, largest_slice, score_labels, score_masks

__all__ = [
    "CLASSES", "METRIC_KEYS", "AverageBaseline", "arse", "average_baseline", "centroid_mm", "confusion",
    "count_unscored", "diameter_mm", "dice", "f1_from", "largest_slice", "mean_std", "precision_from",
    "recall_from", "score_baseline", "score_baseline_set", "score_label_pair", "score_labels", "score_masks",
    "score_prediction_set", "slice_diameters_mm", "summarise", "truth_fingerprint",
]
