"""``less bench train``: seconds per training step and per inference forward, LESS vs GLOBAL."""

from __future__ import annotations

import click

from lesscli.cli.common import config_resolved, device_option, format_option, set_options, threads_option


@click.command("train")
@click.option("--quick", is_flag=True, help="Default size only, 200-step scans, one repeat.")
@click.option("--size", "sizes", multiple=True, type=click.Choice(["default", "paper"]),
              help="Sizes to run (repeatable).  [default: default and paper]")
@click.option("--steps", type=int, default=None, help="Steps per scan.  [default: 1000; quick: 200]")
@click.option("--batch-size", type=int, default=2, show_default=True, help="Scans per batch.")
@click.option("--repeats", type=int, default=None,
              help="Timed repeats after one warm-up.  [default: 3; quick: 1]")
@set_options("SSL sampling, e.g. ssl.k_input=8 ssl.k_query=8 (the paper's sweeps; repeatable).  [default: "
             "16, 16]")
@device_option()
@threads_option()
@format_option()
def cli(quick: bool, sizes: tuple[str, ...], steps: int | None, batch_size: int, repeats: int | None,
        overrides: tuple[str, ...], device: str, threads: int | None, fmt: str | None) -> None:
    """Time a training step (forward + backward + Adam) and an inference forward.

    LESS and GLOBAL at this toolkit's default size (d_z 128, 11x11 particles) and at the paper's
    (d_z 1024, 18x18 particles), on synthetic scans of 1000 steps; ratios are against GLOBAL at the
    same size, measured in the same run. Parameter counts are included.

    Example: less bench train --size paper --set ssl.k_input=8 --set ssl.k_query=8 --threads 1
    """
    from lesscli.bench.train import bench_config, run
    from lesscli.errors import LessError
    from lesscli.io.records import emit_records
    from lesscli.threads import apply_threads
    from lesscli.train.config import to_dict
    from lesscli.train.distributed import resolve_device

    chosen = list(sizes) or (["default"] if quick else ["default", "paper"])
    steps = steps or (200 if quick else 1000)
    repeats = repeats or (1 if quick else 3)
    if steps < 1 or batch_size < 1 or repeats < 1:
        raise LessError("--steps, --batch-size and --repeats must be >= 1")
    cfg = bench_config(overrides)
    config_resolved(to_dict(cfg))
    apply_threads("throughput", override=threads)
    emit_records(run(chosen, steps, batch_size, repeats, resolve_device(device), cfg), fmt)
