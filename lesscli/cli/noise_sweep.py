"""``less noise-sweep imager.pt DATA``: imaging accuracy under i.i.d. Gaussian pose noise."""

from __future__ import annotations

import click

from lesscli.cli.common import checked_figure, comma_list, device_option, format_option, seed_option

TABLE_COLUMNS = ["pos_mm", "ang_rad", "repeats", "f1_micro", "f1_micro_std", "f1", "f1_std", "com_error_mm",
                 "com_error_mm_std", "diameter_error_mm"]


def _levels(text: str, what: str) -> list[float]:
    values = comma_list(text, float, what)
    if not values or min(values) < 0:
        raise click.BadParameter(f"'{text}': need one or more sigmas >= 0", param_hint=what)
    return list(dict.fromkeys(values))


@click.command("noise-sweep")
@click.argument("model", type=click.Path(), metavar="IMAGER.pt")
@click.argument("data", type=click.Path())
@click.option("--pos-mm", default="0,0.25,0.5,1,2,4", show_default=True,
              help="Position noise sigmas (x, y, z), mm.")
@click.option("--ang-rad", default="0,0.02,0.05,0.1,0.2", show_default=True,
              help="Angle noise sigmas (roll, pitch, yaw), rad.")
@click.option("--repeats", type=click.IntRange(min=1), default=3, show_default=True,
              help="Noise draws per cell.")
@seed_option()
@click.option("--plot", "plot_path", type=click.Path(), default=None, callback=checked_figure,
              help="Figure (.png, .pdf or .svg): the metric vs position noise, one line per angle level.")
@click.option("--metric", type=click.Choice(["f1_micro", "f1", "com_error_mm", "diameter_error_mm"]),
              default="f1_micro", show_default=True, help="Plotted metric.")
@click.option("--threshold", type=click.FloatRange(0, 1), default=None,
              help="Pillar/inclusion only above this probability. Default: argmax.")
@click.option("--grow", is_flag=True, help="Extend the particle grid over larger label grids (same spacing).")
@click.option("--batch-size", type=click.IntRange(min=1), default=4, show_default=True,
              help="Scans imaged together (memory against speed).")
@device_option()
@format_option()
def cli(model, data, pos_mm, ang_rad, repeats, seed, plot_path, metric, threshold, grow, batch_size, device,
        fmt) -> None:
    """Re-predict DATA with i.i.d. Gaussian noise on the pad poses and score the inclusion class.

    Noise is added to every step's pose in the phantom frame of the scan set (x, y, z mm with
    sigma --pos-mm; roll, pitch, yaw rad with sigma --ang-rad), for every combination of the two
    lists and --repeats draws each (the same seeded draws scaled for every cell; the noise-free
    cell is computed once). One record per cell: mean and std over repeats of the micro F1 over the
    set, the mean per-scan F1, centroid and diameter errors (3D metrics for a 3D model, 2D for 2D).

    Example: less noise-sweep imager.pt split/test.npz --pos-mm 0,1,2 --ang-rad 0,0.1 --repeats 3
    --plot noise.png
    """
    from lesscli.cli.common import progress
    from lesscli.data.compat import for_model
    from lesscli.errors import DataError
    from lesscli.infer.noise import grid_levels, sweep
    from lesscli.infer.predict import PredictOptions, load_imager, predict
    from lesscli.io.records import emit_records
    from lesscli.io.scans import load_scans
    from lesscli.train.distributed import resolve_device

    levels = grid_levels(_levels(pos_mm, "--pos-mm"), _levels(ang_rad, "--ang-rad"))
    dev = resolve_device(device)
    imager, ckpt = load_imager(model, dev)
    scans = for_model(load_scans(data), ckpt, model, data)
    if not any(scans.label_of(s) is not None for s in range(scans.n_scans)):
        raise DataError(f"{data}: no scan has a label volume, so nothing can be scored")
    opts = PredictOptions(threshold=threshold, grow=grow, batch_size=batch_size)
    dim = int(ckpt["config"]["image"]["dim"])

    def predict_fn(noisy):
        return predict(imager, ckpt, noisy, opts, dev, name=data)

    rows = sweep(predict_fn, scans, levels, repeats, seed, dim, progress=progress)
    rows = [{**r, "dim": dim, "model": ckpt["config"]["encoder"]["name"], "seed": seed} for r in rows]
    if plot_path:
        from lesscli.plots.sweeps import noise_figure

        noise_figure(rows, plot_path, metric, title=f"Pose noise: {model} on {data}")
    emit_records(rows, fmt, columns=TABLE_COLUMNS)
