"""Aggregation of metric rows: means over valid values, std (ddof=1) and the count of valid values.

``summarise(rows, group_by)`` returns one row per group with, for each metric ``k``: ``k`` the
mean over the rows where it is defined, ``k_std`` the sample standard deviation (ddof=1; None with
fewer than two valid values) and ``k_n`` the number of valid values, plus ``n`` the number of rows.
Undefined values (None/NaN) are never counted as 0. When the rows carry voxel counts
(``tp_S fp_S fn_S``) the micro precision/recall/F1 over the group are added (``f1_micro_S``...).

Used twice by ``less metrics``: scans -> one row per file (mean over scans, micro F1 over the
set), then files -> one row per group (mean +- std over seeds, as the paper's tables).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from lesscli.metrics.masks import f1_from, precision_from, recall_from
from lesscli.metrics.volume import METRIC_KEYS

_MICRO = {"precision_micro": precision_from, "recall_micro": recall_from, "f1_micro": f1_from}


def _valid(values: Iterable) -> list[float]:
    out = []
    for v in values:
        if v is None or isinstance(v, bool):
            continue
        v = float(v)
        if math.isfinite(v):
            out.append(v)
    return out


def mean_std(values: Iterable) -> tuple[float | None, float | None, int]:
    """(mean, std with ddof=1, n_valid) over the defined values; None where not computable."""
    vals = _valid(values)
    if not vals:
        return None, None, 0
    arr = np.asarray(vals, np.float64)
    return float(arr.mean()), (float(arr.std(ddof=1)) if len(arr) > 1 else None), len(arr)


def _micro(rows: Sequence[Mapping]) -> dict:
    out: dict = {}
    for suffix in ("3d", "2d"):
        keys = (f"tp_{suffix}", f"fp_{suffix}", f"fn_{suffix}")
        counted = [r for r in rows if all(r.get(k) is not None for k in keys)]
        if not any(keys[0] in r for r in rows):
            continue
        tp, fp, fn = (sum(int(r[k]) for r in counted) for k in keys)
        out.update({f"{name}_{suffix}": fn_(tp, fp, fn) for name, fn_ in _MICRO.items()})
    return out


def _group_key(row: Mapping, group_by: Sequence[str]) -> tuple:
    return tuple(row.get(k) for k in group_by)


def summarise(rows: Iterable[Mapping], group_by: Sequence[str] = (), metrics: Sequence[str] | None = None,
              label: str = "group") -> list[dict]:
    """One summary row per group of ``rows`` (groups in order of first appearance).

    Args:
        rows: metric rows (per scan, or per file summaries).
        group_by: keys whose values define a group (missing keys group as None).
        metrics: keys to aggregate; default: the known metric keys present in the rows.
        label: value of the ``row`` key of the summaries.

    Returns:
        list of dicts: ``row``, the group keys, ``n``, then ``k``, ``k_std``, ``k_n`` per metric and
        the micro scores when voxel counts are present.
    """
    rows = list(rows)
    if metrics is None:
        present = set().union(*(r.keys() for r in rows)) if rows else set()
        metrics = [k for k in METRIC_KEYS if k in present]
    groups: dict[tuple, list[Mapping]] = {}
    for row in rows:
        groups.setdefault(_group_key(row, group_by), []).append(row)
    out = []
    for key, members in groups.items():
        summary = {"row": label, **dict(zip(group_by, key)), "n": len(members)}
        for metric in metrics:
            mean, std, n_valid = mean_std(r.get(metric) for r in members)
            summary.update({metric: mean, f"{metric}_std": std, f"{metric}_n": n_valid})
        summary.update(_micro(members))
        out.append(summary)
    return out


def pm_cells(row: Mapping, metrics: Sequence[str], digits: int = 3) -> dict:
    """Display strings ``mean +- std (n)`` for a summary row (for tables; JSON keeps the numbers)."""
    cells = {}
    for metric in metrics:
        mean, std, n = row.get(metric), row.get(f"{metric}_std"), row.get(f"{metric}_n")
        if mean is None:
            cells[metric] = None if n is None else f"- (n={n})"
            continue
        text = f"{mean:.{digits}g}" + ("" if std is None else f" ± {std:.2g}")
        cells[metric] = text + ("" if n is None else f" (n={n})")
    return cells
