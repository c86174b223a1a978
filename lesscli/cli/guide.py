"""``less guide MODEL PARTIAL``: the next touch locations that most reduce the image's uncertainty."""

from __future__ import annotations

import click

from lesscli.cli.common import (
    LATENCY_THREADS,
    checked_output,
    device_option,
    format_option,
    labelling_options,
    threads_option,
)


@click.command("guide")
@click.argument("model", type=click.Path())
@click.argument("partial", type=click.Path())
@click.option("--k", "k", type=click.IntRange(min=1), default=5, show_default=True,
              help="Touch locations to suggest.")
@click.option("--scan", "scan_index", type=click.IntRange(min=0), default=None,
              help="Only this scan of PARTIAL (default: every scan).")
@click.option("--plot", "plot_path", type=click.Path(), default=None, callback=checked_output(),
              help="Overlay PNG (image | uncertainty + suggestions | touches); needs one scan.")
@click.option("--radius-mm", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Disc a touch resolves (default: the model's receptive field).")
@click.option("--exclusion-mm", type=click.FloatRange(min=0), default=None,
              help="Minimum distance between suggestions (default: --radius-mm).")
@click.option("--margin-mm", type=click.FloatRange(min=0), default=3.0, show_default=True,
              help="Keep suggestions this far inside the phantom outline.")
@click.option("--width-mm", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Phantom octagon across flats (default: the scan's label footprint, else 60 mm).")
@click.option("--score", default="entropy", show_default=True,
              help="Uncertainty to cover: 'entropy' (all classes) or 'inclusion' (inclusion vs the rest).")
@labelling_options()
@device_option()
@threads_option(LATENCY_THREADS)
@format_option()
def cli(model, partial, k, scan_index, plot_path, radius_mm, exclusion_mm, margin_mm, width_mm, score,
        threshold, min_volume_mm3, smooth_mm, device, threads, fmt) -> None:
    """Suggest the next K touches (x, y mm) for each scan of the partial scan set PARTIAL.

    The partial scan is imaged with MODEL; touches go where the most entropy lies within a touch's
    reach (a disc of the receptive-field radius), greedily, at least --exclusion-mm apart and inside
    the phantom outline. One JSON line per suggestion, best first.

    Example: less guide imager.pt partial.npz --k 5 --plot overlay.png
    """
    from lesscli.errors import DataError
    from lesscli.infer.guide import UNCERTAINTY, GuideOptions, guide_scan
    from lesscli.infer.predict import load_imager, scans_for_model
    from lesscli.io.records import emit_records
    from lesscli.models.registry import lookup
    from lesscli.threads import apply_threads
    from lesscli.train.distributed import resolve_device

    lookup(UNCERTAINTY, score, "guide score")
    imager, ckpt = load_imager(model, resolve_device(device))
    scans = scans_for_model(partial, ckpt, model)
    if scan_index is not None and scan_index >= scans.n_scans:
        raise DataError(f"{partial}: has {scans.n_scans} scans, no scan {scan_index}")
    chosen = [scan_index] if scan_index is not None else list(range(scans.n_scans))
    if plot_path and len(chosen) != 1:
        raise click.UsageError(f"--plot draws one scan; {partial} has {scans.n_scans}: pick one with --scan")
    apply_threads("latency", threads)
    opts = GuideOptions(k, radius_mm, exclusion_mm, margin_mm, score)
    rows = []
    for s in chosen:
        g = guide_scan(imager, ckpt, scans, s, opts, width_mm, threshold, min_volume_mm3, smooth_mm)
        rows += [{"scan": s, "insert": str(scans.scan_insert[s]), "steps": len(g.touches_xy_mm), **r}
                 for r in g.rows]
        if plot_path:
            _plot(plot_path, g, str(scans.scan_insert[s]))
    emit_records(rows, fmt)


def _plot(path: str, g, insert: str) -> None:
    import numpy as np

    from lesscli.io.atomic import atomic_path
    from lesscli.plots.monitor import monitor_frame

    marks = np.array([[r["x_mm"], r["y_mm"]] for r in g.rows]).reshape(-1, 2)
    with atomic_path(path, ".png") as tmp:
        monitor_frame(tmp, g.labels, g.entropy, g.touches_xy_mm, g.grid.origin_mm, g.grid.spacing_mm, 4,
                      title=f"{insert}: next {len(marks)} touches", marks_xy_mm=marks)
