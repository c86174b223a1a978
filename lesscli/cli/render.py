"""``less render pred.npz -o DIR``: PNG figures of predictions (truth | prediction | uncertainty);
with several prediction files of the same scans, truth | one image per file."""

from __future__ import annotations

import os

import click

from lesscli.cli.common import format_option, output_option


def _stem(g: int, final) -> str:
    return f"scan{g:03d}_{final.insert or 'scan'}_o{final.orientation}"


def _title(final) -> str:
    return f"{final.insert} orientation {final.orientation}, {final.steps} steps"


def _render_one(preds, groups, chosen, tmp: str, output: str) -> list[dict]:
    """Panels (truth | prediction | uncertainty) per scan, and the strip over time for --steps files."""
    from lesscli.cli.common import progress
    from lesscli.plots.render import scan_figure, strip_figure

    rows = []
    for g in progress(chosen, desc="render", leave=False):
        members = [preds[i] for i in groups[g]]
        final, stem = members[-1], _stem(g, members[-1])
        scan_figure(final, os.path.join(tmp, stem + ".png"), _title(final))
        rows.append({"scan": g, "insert": final.insert, "orientation": final.orientation, "kind": "panels",
                     "steps": final.steps, "figure": os.path.join(output, stem + ".png")})
        if len(members) > 1:
            strip_figure(members, os.path.join(tmp, stem + "_steps.png"), _title(final) + " (over time)")
            rows.append({"scan": g, "insert": final.insert, "orientation": final.orientation, "kind": "strip",
                         "steps": [m.steps for m in members],
                         "figure": os.path.join(output, stem + "_steps.png")})
    return rows


def _finals(paths, loaded) -> list[list]:
    """Per file, the final prediction of each scan; every file must hold the same scans on the same grids."""
    from lesscli.errors import DataError
    from lesscli.plots.render import group_scans

    finals = [[p.scans[g[-1]] for g in group_scans(p.scans)] for p in loaded]
    for path, scans in zip(paths[1:], finals[1:]):
        if len(scans) != len(finals[0]):
            raise DataError(f"{path}: {len(scans)} scans, but {paths[0]} has {len(finals[0])}; "
                            "render several files only for predictions of the same scan set")
        for g, (a, b) in enumerate(zip(finals[0], scans)):
            if (a.insert, a.orientation, a.label.shape) != (b.insert, b.orientation, b.label.shape):
                raise DataError(f"{path}: scan {g} is {b.insert} orientation {b.orientation} on grid "
                                f"{b.label.shape}, but in {paths[0]} {a.insert} orientation {a.orientation} "
                                f"on grid {a.label.shape}; predict the same scan set with each imager")
    return finals


def _render_compare(paths, loaded, chosen, tmp: str, output: str) -> list[dict]:
    """Truth | the final image of each file per scan, columns titled by the files' model (else file name)."""
    from lesscli.cli.common import progress
    from lesscli.plots.render import compare_figure

    finals = _finals(paths, loaded)
    names = [p.meta.get("model") or os.path.basename(path) for path, p in zip(paths, loaded)]
    if len(set(names)) < len(names):
        names = [os.path.basename(path) for path in paths]
    rows = []
    for g in progress(chosen, desc="render", leave=False):
        final, stem = finals[0][g], _stem(g, finals[0][g])
        compare_figure([f[g] for f in finals], names, os.path.join(tmp, stem + ".png"), _title(final))
        rows.append({"scan": g, "insert": final.insert, "orientation": final.orientation, "kind": "compare",
                     "models": names, "figure": os.path.join(output, stem + ".png")})
    return rows


@click.command("render")
@click.argument("predictions", type=click.Path(), nargs=-1, required=True,
                metavar="PRED.npz [PRED.npz ...]")
@output_option(help="Output folder for the PNG files (created if missing).", folder=True)
@click.option("--scan", "scans", type=int, multiple=True,
              help="Render only these scans (0-based; repeatable).")
@format_option()
def cli(predictions: tuple[str, ...], output: str, scans: tuple[int, ...], fmt: str | None) -> None:
    """Per scan, truth | prediction | uncertainty side by side (top view and slices for 3D, colour
    legend, entropy colour bar), and for '--steps' predictions a strip of the image developing over
    time. With several prediction files of the same scans (e.g. two imagers of one test set), one
    figure per scan instead: truth | the final image of each file, columns titled by the files'
    model. One record per figure goes to stdout.

    Examples:

      less render pred.npz -o figures/

      less render pred_less.npz pred_forcemap.npz -o compare/
    """
    from lesscli.errors import DataError
    from lesscli.io.atomic import atomic_dir
    from lesscli.io.predictions import load_predictions
    from lesscli.io.records import emit_records
    from lesscli.plots.render import group_scans

    loaded = [load_predictions(p) for p in predictions]
    groups = group_scans(loaded[0].scans)
    chosen = list(scans) or list(range(len(groups)))
    bad = [s for s in chosen if not 0 <= s < len(groups)]
    if bad:
        raise DataError(f"{predictions[0]}: scan {bad[0]} does not exist (the file holds {len(groups)} "
                        "scans)")
    with atomic_dir(output) as tmp:
        if len(loaded) == 1:
            rows = _render_one(loaded[0].scans, groups, chosen, tmp, output)
        else:
            rows = _render_compare(predictions, loaded, chosen, tmp, output)
    emit_records(rows, fmt)
