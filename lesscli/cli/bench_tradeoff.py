"""``less bench tradeoff``: accuracy against time for the knobs that trade them."""

from __future__ import annotations

import click

from lesscli.cli.common import (
    checked_output,
    comma_list,
    device_option,
    format_option,
    seed_option,
    threads_option,
)

TABLE_COLUMNS = ["knob", "value", "sim_s", "pretrain_s", "fit_s", "train_s", "train_s_ratio",
                 "latency_ms_per_scan", "f1_single", "f1_multiple", "f1_single_delta", "f1_multiple_delta"]


def _parse_values(items: tuple[str, ...], knobs: dict, base) -> dict[str, tuple]:
    """``KNOB=V1,V2`` items -> knob -> values, typed like the base setting's field."""
    out = {}
    for item in items:
        knob, _, text = item.partition("=")
        if knob not in knobs or not text:
            raise click.BadParameter(f"'{item}': expected KNOB=V1,V2 with KNOB in {', '.join(knobs)}",
                                     param_hint="--values")
        out[knob] = comma_list(text, type(getattr(base, knobs[knob])), f"--values {knob}")
    return out


@click.command("tradeoff")
@click.option("--quick", is_flag=True, help="Minutes on a CPU: small data, few epochs, few values per knob.")
@click.option("--knob", "knobs", multiple=True, metavar="NAME",
              help="Vary only these knobs (repeatable): tier, receptive_field, spacing, dim, width, "
                   "subsample, epochs, turns (prediction only).")
@click.option("--inserts", type=click.IntRange(min=4), default=None,
              help="Single-inclusion inserts to simulate (a quarter held out for testing).")
@click.option("--n-traj", type=click.IntRange(min=2), default=None, help="Pokes per scan.")
@click.option("--epochs", type=click.IntRange(min=1), default=None,
              help="Base SSL epochs (the epochs knob varies it).")
@click.option("--image-epochs", type=click.IntRange(min=1), default=None, help="Imaging epochs per setting.")
@click.option("--values", "values", multiple=True, metavar="KNOB=V1,V2",
              help="Values tried for a knob, e.g. --values receptive_field=5,10,20 (repeatable).")
@click.option("--work-dir", type=click.Path(), default=None,
              help="Keep the checkpoints here (default: a temporary folder).")
@click.option("--plot", "plot_path", type=click.Path(), default=None, callback=checked_output(),
              help="PNG: F1 on single and multiple vs training time (Pareto).")
@click.option("--knob-plot", "knob_plot", type=click.Path(), default=None, callback=checked_output(),
              help="PNG: F1 on single and multiple against the value of the (one) chosen knob.")
@device_option()
@threads_option()
@seed_option()
@format_option()
def cli(quick, knobs, inserts, n_traj, epochs, image_epochs, values, work_dir, plot_path, knob_plot, device,
        threads, seed, fmt) -> None:
    """For each setting (one knob changed from the base): simulate (once per tier), pretrain,
    fit a 3D imager, predict held-out single inserts and the multiple set, and score them, all on
    the same data in one run. One record per setting: simulation, pretraining, fitting and total
    training seconds, inference latency per scan, micro F1 (inclusion, 3D) on single and multiple,
    and ratios / differences against the base setting.

    Example: less bench tradeoff --quick --plot tradeoff.png --format table
    """
    import tempfile

    from lesscli.bench.tradeoff import FULL, KNOBS, QUICK, TradeoffRun, make_plan, run_tradeoff
    from lesscli.cli.common import check_known, progress
    from lesscli.io.records import emit_records
    from lesscli.threads import apply_threads

    check_known(knobs, KNOBS, "knob", "--knob")
    if knob_plot and len(set(knobs)) != 1:
        raise click.UsageError("--knob-plot needs exactly one --knob")
    apply_threads("throughput", override=threads)
    plan = make_plan(quick, _parse_values(values, KNOBS, (QUICK if quick else FULL).base), epochs,
                     single_inserts=inserts, n_traj=n_traj, image_epochs=image_epochs)
    with tempfile.TemporaryDirectory(prefix="less-tradeoff-") as tmp:
        run = TradeoffRun(workdir=work_dir or tmp, device=device, seed=seed, progress=progress)
        rows = run_tradeoff(plan, list(knobs) or list(KNOBS), run)
    if plot_path or knob_plot:
        from lesscli.plots.sweeps import line_figure, pareto_figure

        if plot_path:
            pareto_figure(rows, plot_path, title="LESS: F1 against training time (one knob at a time)")
        if knob_plot:
            line_figure(rows, knob_plot, "value", ["f1_single", "f1_multiple"], knobs[0],
                        title=f"LESS: F1 on single and multiple against {knobs[0]}")
    emit_records(rows, fmt, columns=TABLE_COLUMNS)
