"""``less metrics``: imaging metrics in millimetres for prediction files or NIfTI label volumes."""

from __future__ import annotations

import sys

import click

from lesscli.cli.common import LOG, check_known, format_option

# Columns shown in tables (JSON formats keep every key).
SCAN_COLUMNS = ("file", "model", "scan", "insert", "orientation", "f1_3d", "com_error_mm_3d", "arse_3d",
                "diameter_error_mm_3d", "volume_error_mm3", "f1_2d", "com_error_mm_2d", "arse_2d",
                "diameter_error_mm_2d", "area_error_mm2")
FILE_TABLE_KEYS = ("file", "model")   # identity columns of the per-file table
SUMMARY_METRICS = ("f1_micro_3d", "f1_3d", "com_error_mm_3d", "arse_3d", "diameter_error_mm_3d",
                   "volume_error_mm3", "f1_micro_2d", "f1_2d", "com_error_mm_2d", "arse_2d",
                   "diameter_error_mm_2d", "area_error_mm2")


def _split_keys(values: tuple[str, ...]) -> tuple[str, ...] | None:
    keys = tuple(k.strip() for v in values for k in v.split(",") if k.strip())
    return keys or None


def _check_usage(preds, truth_path, pred_nifti, baseline_from, threshold) -> None:
    if bool(truth_path) != bool(pred_nifti):
        raise click.UsageError("--truth and --pred go together (a reference and the volumes to score)")
    if not preds and not truth_path:
        raise click.UsageError("give prediction files, or --truth REF.nii.gz --pred SEG.nii.gz")
    if baseline_from and not preds:
        raise click.UsageError("--baseline-from needs prediction files (it scores the baseline on their "
                               "truths)")
    if threshold is not None and not preds:
        raise click.UsageError("--threshold needs prediction files with probabilities")


def _groups_repeat_files(report) -> bool:
    """True when each group summary is one file's summary under keys the per-file table shows already
    (e.g. ``--group-by model`` with one file per model): the table then shows the per-file rows only."""
    return set(report.group_by) <= set(FILE_TABLE_KEYS) and all(g["n"] == 1 for g in report.groups)


def _shown(show: tuple[str, ...] | None) -> tuple[str, ...]:
    """The metrics the human tables show, in order: ``show`` (checked), else every one."""
    check_known(show or (), SUMMARY_METRICS, "metric", "--show")
    return show or SUMMARY_METRICS


def _emit_tables(report, fmt: str, summary_only: bool, show: tuple[str, ...]) -> None:
    from lesscli.io.records import emit_records
    from lesscli.metrics.summary import pm_cells

    blocks = []
    if not summary_only and report.scans:
        names = [c for c in SCAN_COLUMNS if c not in SUMMARY_METRICS] + [m for m in show if m in SCAN_COLUMNS]
        cols = [c for c in names if any(c in r for r in report.scans)]
        blocks.append((report.scans, cols))
    groups = [] if _groups_repeat_files(report) else report.groups
    for rows, keys in ((report.files, FILE_TABLE_KEYS), (groups, report.group_by)):
        if rows:
            metrics = [m for m in show if any(r.get(m) is not None or r.get(f"{m}_n") for r in rows)]
            shown = [{**{k: r.get(k) for k in (*keys, "n")}, **pm_cells(r, metrics)} for r in rows]
            blocks.append((shown, [*keys, "n", *metrics]))
    for i, (rows, cols) in enumerate(blocks):
        if i:
            sys.stdout.write("\n")
        emit_records(rows, fmt, columns=list(cols))


@click.command("metrics")
@click.argument("preds", type=click.Path(), nargs=-1, metavar="[PRED.npz ...]")
@click.option("--truth", "truth_path", type=click.Path(), default=None,
              help="Reference label volume (NIfTI) for --pred.")
@click.option("--pred", "pred_nifti", type=click.Path(), multiple=True,
              help="Predicted label volume (NIfTI); repeatable.")
@click.option("--cls", type=click.Choice(["inclusion", "pillar"]), default="inclusion", show_default=True,
              help="Class to score.")
@click.option("--threshold", type=click.FloatRange(0.0, 1.0), default=None,
              help="Re-label from the probabilities: pillar/inclusion only above this probability.")
@click.option("--baseline-from", "baseline_from", type=click.Path(), default=None,
              help="Training scan set with labels: add the average-prediction baseline (model 'average').")
@click.option("--diameter-points", type=click.Choice(["centres", "corners"]), default="centres",
              show_default=True, help="Diameter between pixel centres (the paper) or pixel corners.")
@click.option("--group-by", "group_by", multiple=True, metavar="KEY[,KEY]",
              help="Group summaries by these keys (set, seed, model, dim, insert, any meta key).")
@click.option("--summary-only", is_flag=True, help="Only the per-file and group summaries.")
@click.option("--show", multiple=True, metavar="METRIC[,METRIC]",
              help="The metrics a table shows, in this order (default: every one; implies --format table "
                   "unless markdown is asked for; JSON formats keep every metric).")
@format_option()
def cli(preds, truth_path, pred_nifti, cls, threshold, baseline_from, diameter_points, group_by, summary_only,
        show, fmt) -> None:
    """Score predictions against their truth: F1/precision/recall, centroid error (mm), ARSE,
    diameter error (mm), area/volume error (mm^2/mm^3), in 3D and on the largest true slice (2D).

    Output: one row per scan, one summary row per file and model (mean over scans and micro F1 over
    the set), and, for several files or with --group-by, one row per group with mean +- std (ddof=1)
    over files and the count of valid values. Undefined values are null and not counted.
    --baseline-from adds the baseline (model 'average') once per distinct set of truths. Several
    models of one test set (one file each) with --group-by model make one table in the human
    formats: a row per model plus 'average' (the group rows would repeat them).

    Examples:

      less metrics pred_s0.npz pred_s1.npz pred_s2.npz --summary-only --format table

      less metrics pred_less.npz pred_forcemap.npz --baseline-from train.npz --group-by model --summary-only

      less metrics --truth ref.nii.gz --pred seg.nii.gz

      less metrics pred.npz --summary-only --show f1_micro_3d,com_error_mm_3d,diameter_error_mm_3d
    """
    from lesscli.io.records import emit_records, resolve_format
    from lesscli.metrics.report import (
        FILE_KEYS,
        SCAN_KEYS,
        Report,
        add_summaries,
        load_baseline,
        score_files,
        score_nifti_pairs,
    )

    _check_usage(preds, truth_path, pred_nifti, baseline_from, threshold)
    shown = _shown(_split_keys(show))
    if show and fmt in ("json", "jsonl"):
        raise click.UsageError(f"--show picks a table's columns; --format {fmt} keeps every metric")
    keys = _split_keys(group_by)
    extra = tuple(k for k in keys or () if k not in FILE_KEYS and k not in SCAN_KEYS)
    report = Report()
    if preds:
        baseline = load_baseline(baseline_from, cls, diameter_points) if baseline_from else None
        score_files(preds, cls, threshold, diameter_points, baseline, baseline_from or "", extra, report)
    if truth_path:
        score_nifti_pairs(truth_path, pred_nifti, cls, diameter_points, report)
    check_known(keys or (), report.group_keys(), "key", "--group-by")
    for message in report.warnings:
        LOG.warning(message)
    add_summaries(report, keys)
    fmt = resolve_format(fmt or ("table" if show else None))
    if fmt in ("table", "markdown"):
        _emit_tables(report, fmt, summary_only, shown)
    else:
        emit_records([*([] if summary_only else report.scans), *report.files, *report.groups], fmt)
