"""``less render pred.npz -o DIR``: PNG figures of predictions (truth | prediction | uncertainty)."""

from __future__ import annotations

import click

from lesscli.cli.common import format_option, output_option


@click.command("render")
@click.argument("predictions")
@output_option(help="Output folder for the PNG files (created if missing).")
@click.option("--scan", "scans", type=int, multiple=True, help="Render only these scans (0-based; repeatable).")
@format_option
def cli(predictions: str, output: str, scans: tuple[int, ...], fmt: str | None) -> None:
    """Per scan, truth | prediction | uncertainty side by side (top view and slices for 3D, colour
    legend, entropy colour bar), and for '--steps' predictions a strip of the image developing over
    time. One record per figure goes to stdout.

    Example: less render pred.npz -o figures/
    """
    import os

    from lesscli.cli.common import progress
    from lesscli.errors import DataError
    from lesscli.io.atomic import atomic_dir
    from lesscli.io.predictions import load_predictions
    from lesscli.io.records import emit_records
    from lesscli.plots.render import group_scans, scan_figure, strip_figure

    preds = load_predictions(predictions).scans
    groups = group_scans(preds)
    chosen = list(scans) or list(range(len(groups)))
    bad = [s for s in chosen if not 0 <= s < len(groups)]
    if bad:
        raise DataError(f"{predictions}: scan {bad[0]} does not exist (the file holds {len(groups)} scans)")
    rows = []
    with atomic_dir(output) as tmp:
        for g in progress(chosen, desc="render", leave=False):
            members = [preds[i] for i in groups[g]]
            final = members[-1]
            stem = f"scan{g:03d}_{final.insert or 'scan'}_o{final.orientation}"
            title = f"{final.insert} orientation {final.orientation}, {final.steps} steps"
            scan_figure(final, os.path.join(tmp, stem + ".png"), title)
            rows.append({"scan": g, "insert": final.insert, "orientation": final.orientation, "kind": "panels",
                         "steps": final.steps, "figure": os.path.join(output, stem + ".png")})
            if len(members) > 1:
                strip_figure(members, os.path.join(tmp, stem + "_steps.png"), title + " (over time)")
                rows.append({"scan": g, "insert": final.insert, "orientation": final.orientation, "kind": "strip",
                             "steps": [m.steps for m in members],
                             "figure": os.path.join(output, stem + "_steps.png")})
    emit_records(rows, fmt)
