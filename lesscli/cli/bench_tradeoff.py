"""``less bench tradeoff``: what accuracy costs in time, around the demo's imager, over several seeds."""

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

TABLE_COLUMNS = ["model", "knob", "value", "seeds", "f1_single", "f1_single_std", "f1_single_effect",
                 "f1_multiple", "f1_multiple_std", "f1_multiple_effect", "com_error_mm_single", "train_s",
                 "train_s_ratio", "latency_ms", "latency_ms_ratio", "stream_ms", "stream_ms_ratio",
                 "peak_train_mb", "peak_predict_mb", "note"]
MODEL_NAMES = ("less-taxel", "less", "global", "global-taxel", "forcemap")


def _parse_values(items: tuple[str, ...], model: str) -> dict[str, tuple]:
    """``KNOB=V1,V2`` items -> knob -> values, typed like the setting's field and checked."""
    from lesscli.bench.tradeoff import BASES, KNOBS, VALUE_RULES, knobs_for

    out = {}
    for item in items:
        knob, _, text = item.partition("=")
        if knob not in knobs_for(model) or not text:
            raise click.BadParameter(f"'{item}': expected KNOB=V1,V2 with KNOB one of {model}'s knobs: "
                                     f"{', '.join(knobs_for(model))}", param_hint="--values")
        values = comma_list(text, type(getattr(BASES[model], KNOBS[knob].field)), f"--values {knob}")
        test, rule = VALUE_RULES[knob]
        bad = [v for v in values if not test(v)]
        if bad:
            raise click.BadParameter(f"{knob}={bad[0]}: must be {rule}", param_hint="--values")
        out[knob] = values
    return out


def _check_knobs(knobs: tuple[str, ...], model: str) -> None:
    from lesscli.bench.tradeoff import KNOBS, knobs_for

    for knob in knobs:
        if knob not in KNOBS:
            raise click.BadParameter(f"unknown knob '{knob}'; one of {', '.join(KNOBS)}", param_hint="--knob")
        if knob not in knobs_for(model):
            raise click.BadParameter(f"'{knob}' does not apply to {model}; its knobs: "
                                     f"{', '.join(knobs_for(model))}",
                                     param_hint="--knob")


@click.command("tradeoff")
@click.option("--model", type=click.Choice(MODEL_NAMES), default="less-taxel", show_default=True,
              help="The imager whose knobs are measured (forcemap: the classical imager).")
@click.option("--quick", is_flag=True,
              help="The base and every prediction knob, 2 seeds (about 15 min on 2 cores); "
                                            "without it every knob, 3 seeds.")
@click.option("--knob", "knobs", multiple=True, metavar="NAME",
              help="Vary only these knobs (repeatable; default: every knob of the plan that applies to the "
                   "model).")
@click.option("--values", "values", multiple=True, metavar="KNOB=V1,V2",
              help="Values tried for a knob besides the base's, e.g. --values receptive_field=5,20 "
                   "(repeatable).")
@click.option("--seeds", type=click.IntRange(min=1), default=None,
              help="Training seeds per setting (default: 2 with --quick, else 3).")
@click.option("--family", type=click.IntRange(min=4), default=None,
              help="Randomised training inserts (default: the demo's 120; 15 % held out for validation).")
@click.option("--heldout", type=click.IntRange(min=1, max=16), default=None,
              help="Catalogue single inserts imaged, of the demo's 16 (two orientations each).")
@click.option("--multiple", type=click.IntRange(min=1, max=10), default=None,
              help="Catalogue multiple-inclusion inserts imaged (default: all 10).")
@click.option("--n-traj", type=click.IntRange(min=2), default=None,
              help="Pokes per scan simulated (default: 30).")
@click.option("--epochs", type=click.IntRange(min=1), default=None,
              help="Self-supervised epochs of every setting (default: each setting's own).")
@click.option("--image-epochs", type=click.IntRange(min=1), default=None,
              help="Imaging epochs of every setting (default: the demo's 40).")
@click.option("--work-dir", type=click.Path(), default=None,
              help="Keep the data, checkpoints and finished stages here; a rerun with the same folder "
                   "resumes (default: a temporary folder).")
@click.option("--plot", "plot_path", type=click.Path(), default=None, callback=checked_output(),
              help="Figure: F1 on single and multiple against training time and against prediction latency, "
                   "with each Pareto front and the classical and average references.")
@click.option("--knob-plot", "knob_plot", type=click.Path(), default=None, callback=checked_output(),
              help="Figure: F1 on single and multiple against the value of the (one) chosen knob.")
@device_option()
@threads_option()
@seed_option()
@format_option()
def cli(model, quick, knobs, values, seeds, family, heldout, multiple, n_traj, epochs, image_epochs, work_dir,
        plot_path, knob_plot, device, threads, seed, fmt) -> None:
    """Vary one knob at a time around the model's base (less-taxel: the demo's settings on the demo's
    data) and measure each setting over several training seeds: 3D micro F1 (inclusion) on the demo's
    held-out catalogue inserts (single) and on the multiple-inclusion set with their spread over seeds,
    centroid error, training time, whole-scan prediction latency, streaming update latency and peak
    memory, each also as a ratio to the base measured in the same run. A change of F1 is marked an
    effect only where it exceeds twice the seeds' spread. The classical imager and the
    average-prediction baseline close the table as references.

    Knobs (--knob; which apply to which imager: the error for a wrong one lists them): receptive_field,
    spacing, map_cells, map_pitch, contrast, dim, ssl_epochs, scans, pokes, subsample, width (training);
    smoothing, grid (the classical imager's calibration); turns, predict_subsample, threads, precision
    (prediction only: the trained model is reused; precision is float32, bfloat16 under autocast or
    int8 dynamic quantisation, and a row says where this torch or device cannot).

    Example: less bench tradeoff --quick --plot tradeoff.png --format table
    """
    import tempfile

    from lesscli.bench.tradeoff import HELDOUT, KNOBS, TradeoffRun, knobs_for, make_plan, run_tradeoff
    from lesscli.cli.common import progress
    from lesscli.io.records import emit_records
    from lesscli.threads import apply_threads, deterministic_kernels
    from lesscli.train.distributed import resolve_device

    _check_knobs(knobs, model)
    if knob_plot and (len(set(knobs)) != 1 or knobs[0] in ("contrast", "precision")):
        raise click.UsageError("--knob-plot needs exactly one --knob, with numeric values")
    plan = make_plan(quick, _parse_values(values, model), seeds=seeds, family=family, multiple=multiple,
                     n_traj=n_traj, ssl_epochs=epochs, image_epochs=image_epochs,
                     heldout=HELDOUT[:heldout] if heldout else None)
    chosen = list(knobs) or [k for k in knobs_for(model) if k in plan.values]
    apply_threads("throughput", override=threads)
    deterministic_kernels(resolve_device(device))           # the same bytes on a rerun, as training
    with tempfile.TemporaryDirectory(prefix="less-tradeoff-") as tmp:
        run = TradeoffRun(workdir=work_dir or tmp, device=device, seed=seed, progress=progress)
        rows = run_tradeoff(plan, model, chosen, run)
    if plot_path or knob_plot:
        from lesscli.plots.sweeps import line_figure, pareto_figure

        if plot_path:
            pareto_figure(rows, plot_path, time_key=("train_s", "latency_ms"),
                          title=f"{model}: F1 against training time and prediction latency (one knob at a "
                                "time)")
        if knob_plot:
            line = [{**r, "x": r[KNOBS[knobs[0]].field]} for r in rows if r["knob"] in ("base", knobs[0])]
            line_figure(line, knob_plot, "x", ["f1_single", "f1_multiple"], knobs[0],
                        title=f"{model}: F1 on single and multiple against {knobs[0]}")
    emit_records(rows, fmt, columns=TABLE_COLUMNS)
