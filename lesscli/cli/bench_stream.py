"""``less bench stream``: per-update latency of incremental imaging vs full recomputation.

What is timed, and the baseline measured in the same run, is described in :mod:`lesscli.bench.stream`.
"""

from __future__ import annotations

import click

from lesscli.bench.stream import DEFAULT_STEPS, run_stream, stream_models
from lesscli.cli.common import comma_list, format_option, realtime_option, seed_option, threads_option


@click.command("stream")
@click.option("--quick", is_flag=True, help="Fewer timed updates and full passes (and only 100, 1000 steps).")
@click.option("--steps", "steps_text", default=None,
              help="Comma-separated prefix lengths.  [default: 100,1000,5000]")
@click.option("--updates", type=click.IntRange(1), default=None,
              help="Timed updates per length (default 200, quick 20).")
@click.option("--full-repeats", type=click.IntRange(1), default=None,
              help="Timed full passes (default 10, quick 3).")
@click.option("--dim", type=click.Choice(["2", "3"]), default="3", show_default=True,
              help="Image dimension of the default model (3 = the 'image fit' default).")
@click.option("--width", "width_text", default=None,
              help="Comma-separated decoder widths of the default model to time side by side (default: image "
                   "fit's).")
@click.option("--model", "model_path", type=click.Path(), default=None,
              help="Imaging checkpoint to time instead of the default model.")
@click.option("--load", "load_text", default="0", show_default=True, metavar="N|LIST",
              help="Busy processes beside the measurement: N (rows for 0 and N) or a list such as 0,1,2.")
@click.option("--rate", "rate_hz", type=click.FloatRange(0), default=0.0, metavar="HZ",
              help="Timed samples arrive at this rate, as from a live sensor (the process sleeps between "
                   "them); 0: back to back.  [default: 0]")
@threads_option(help="CPU threads for torch and BLAS (default: the stream command's choice).")
@realtime_option()
@seed_option()
@format_option()
def cli(quick, steps_text, updates, full_repeats, dim, width_text, model_path, load_text, rate_hz, threads,
        realtime, seed, fmt) -> None:
    """Per-update latency (median, p99) of incremental imaging vs full recomputation, as a table."""
    from lesscli.io.records import emit_records

    loads = load_levels(load_text)
    steps = (comma_list(steps_text, int, "--steps") if steps_text else DEFAULT_STEPS[:2] if quick
             else DEFAULT_STEPS)
    if not steps or min(steps) < 1:
        raise click.BadParameter(f"'{steps_text}': need one or more prefix lengths >= 1",
                                 param_hint="--steps")
    widths = comma_list(width_text, int, "--width") if width_text else [None]
    if width_text and (not widths or min(widths) < 8):
        raise click.BadParameter(f"'{width_text}': need one or more widths >= 8", param_hint="--width")
    if width_text and model_path:
        raise click.UsageError("--width sizes the default model; a --model checkpoint has its own")
    models = stream_models(model_path, int(dim), widths, seed)
    emit_records(run_stream(models, steps, loads, updates or (20 if quick else 200),
                            full_repeats or (3 if quick else 10), threads, seed, rate_hz, realtime), fmt)


def load_levels(text: str) -> list[int]:
    """``--load``: ``'N'`` -> [0, N] (quiet and loaded), ``'0,1,2'`` -> those levels in order."""
    levels = list(comma_list(text, int, "--load"))
    if not levels or min(levels) < 0:
        raise click.BadParameter(f"'{text}': need busy-process counts >= 0", param_hint="--load")
    if len(levels) == 1 and levels[0] > 0 and "," not in text:
        levels = [0, *levels]
    return levels
