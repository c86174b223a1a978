"""``less metrics`` as a library call: files -> scan rows, per-file summaries and group summaries.

Grouping: per-file summaries always group the scan rows by file (and model, so the average
baseline stays apart). Group summaries then aggregate the per-file rows by ``group_by`` (mean +-
std over files, e.g. seeds) when every key is a file-level key; when a key varies inside a file
(``insert``, ``orientation``, ``scan``, ``steps``) they aggregate the scan rows directly.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from lesscli.errors import DataError
from lesscli.io.labels import load_nifti_labels
from lesscli.io.predictions import load_predictions
from lesscli.metrics.baseline import AverageBaseline, average_baseline
from lesscli.metrics.score import (
    BASELINE_MODEL,
    META_KEYS,
    count_prefixes,
    count_unscored,
    score_baseline_set,
    score_label_pair,
    score_prediction_set,
    truth_fingerprint,
)
from lesscli.metrics.summary import summarise

FILE_KEYS = ("file", "model", *[k for k in META_KEYS if k != "model"], "cls", "threshold")
SCAN_KEYS = ("scan", "insert", "orientation", "steps")
DEFAULT_GROUP = ("set", "model", "dim", "cls", "threshold")


@dataclass
class Report:
    """Rows of one ``less metrics`` run, each list in output order."""

    scans: list[dict] = field(default_factory=list)
    files: list[dict] = field(default_factory=list)
    groups: list[dict] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    meta_keys: set[str] = field(default_factory=set)  # scalar meta keys seen in the files
    group_by: tuple[str, ...] = ()  # keys of the group summaries (filled by add_summaries)

    def group_keys(self) -> set[str]:
        """Keys valid for grouping: identity keys of the rows and scalar meta keys of the files."""
        return {*FILE_KEYS, *SCAN_KEYS, *self.meta_keys}


def load_baseline(path: str, cls: str, points: str) -> AverageBaseline:
    """The average-prediction baseline from the label volumes of a training scan set."""
    from lesscli.io.scans import load_scans

    scans = load_scans(path)
    volumes = [v for v in (scans.label_of(s) for s in range(scans.n_scans)) if v is not None]
    if not volumes:
        raise DataError(f"{path}: no scan has a label volume; the average baseline needs training labels")
    try:
        return average_baseline(volumes, cls, points)
    except ValueError as exc:
        raise DataError(f"{path}: {exc}") from None


def score_files(paths: Sequence[str], cls: str = "inclusion", threshold: float | None = None,
                points: str = "centres", baseline: AverageBaseline | None = None, baseline_source: str = "",
                extra_keys: tuple[str, ...] = (), report: Report | None = None) -> Report:
    """Score prediction files into ``report.scans`` (baseline rows once per distinct test set, after the
    rows of every file, so the baseline follows the models in the summaries)."""
    report = report or Report()
    seen_truths: set[str] = set()
    baseline_rows: list[dict] = []
    for path in paths:
        preds = load_predictions(path)
        report.meta_keys.update(k for k, v in preds.meta.items()
                                if isinstance(v, (str, int, float, bool)) and k not in ("schema", "version"))
        rows = score_prediction_set(preds, path, cls, threshold, points, extra_keys)
        if not rows:
            raise DataError(f"{path}: no scan has a stored truth; metrics need true labels")
        skipped, prefixes = count_unscored(preds), count_prefixes(preds)
        scans = len(preds.scans) - prefixes
        if prefixes:
            report.warnings.append(f"{path}: {len(preds.scans)} images of {scans} scans (prefixes from image "
                                   "predict --steps/--every); each scan is scored once, on its whole "
                                   "sequence")
        if skipped:
            report.warnings.append(f"{path}: {skipped} of {scans} scans have no truth and were skipped")
        report.scans.extend(rows)
        fingerprint = truth_fingerprint(preds)
        if baseline is not None and fingerprint not in seen_truths:
            seen_truths.add(fingerprint)
            baseline_rows.extend(score_baseline_set(preds, baseline, path, cls, points, baseline_source))
    report.scans.extend(baseline_rows)
    return report


def score_nifti_pairs(truth_path: str, pred_paths: Sequence[str], cls: str = "inclusion",
                      points: str = "centres", report: Report | None = None) -> Report:
    """Score NIfTI label volumes against one reference volume on the same grid."""
    report = report or Report()
    truth = load_nifti_labels(truth_path)
    for path in pred_paths:
        report.scans.append(score_label_pair(load_nifti_labels(path), truth, path, truth_path, cls, points))
    return report


def add_summaries(report: Report, group_by: Sequence[str] | None = None) -> Report:
    """Fill ``report.files`` (one per file and model) and ``report.groups``.

    Args:
        group_by: keys for the group summaries; None means the default grouping
            (set, model, dim, cls, threshold) when more than one file was scored, else none.
            When the rows hold the average baseline, ``model`` is always a group key, so the
            baseline is never pooled with a model.
    """
    extra = [k for k in (group_by or ()) if k not in FILE_KEYS and k not in SCAN_KEYS]
    report.files = summarise(report.scans, (*FILE_KEYS, *extra), label="file")
    n_files = len({row["file"] for row in report.scans})
    if group_by is None:
        group_by = DEFAULT_GROUP if n_files > 1 else ()
    elif "model" not in group_by and any(row.get("model") == BASELINE_MODEL for row in report.scans):
        group_by = ("model", *group_by)
    report.group_by = tuple(group_by)
    if not group_by:
        report.groups = []
    elif any(k in SCAN_KEYS for k in group_by):
        report.groups = summarise(report.scans, tuple(group_by))
    else:
        report.groups = summarise(report.files, tuple(group_by))
    return report
