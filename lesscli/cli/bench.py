"""``less bench NAME``: benchmarks that print ratios against a baseline measured in the same run.

Each benchmark's command is a module ``lesscli.cli.bench_<module>`` exposing ``cli`` and is imported
only when run, like the top-level subcommands; it parses options, calls ``lesscli.bench.<module>``
(where the measurement lives) and emits the records and figures.
"""

from __future__ import annotations

import importlib

import click

from lesscli.cli.common import with_global_options
from lesscli.errors import closest

# name -> (module under lesscli.cli, one-line help)
BENCHES: dict[str, tuple[str, str]] = {
    "metrics": ("bench_metrics",
                "Time to score a 26x128x128 volume with a 16 mm inclusion vs F1-only and all-pairs."),
    "stream": ("bench_stream",
               "Per-update latency of streaming imaging vs full recomputation at 100/1000/5000 steps."),
    "guide": ("bench_guide", "Closed loop: F1 vs touches for guided, raster and random touch order."),
    "train": ("bench_train",
              "Seconds per training step and inference forward, LESS vs GLOBAL, default and paper sizes."),
    "tradeoff": ("bench_tradeoff", "Accuracy vs time: each knob of an imager around the demo's, over seeds."),
    "mri": ("bench_mri", "Seconds to label a 256^3 synthetic MRI volume on one core vs plain thresholding."),
    "sim": ("bench_sim",
            "Contact tiers: error vs closed forms / finest FEM against time per step, scan time."),
    "pose": ("bench_pose",
             "AprilTag sensor-pose error and time per frame: refinements vs the plain pipeline."),
    "imaging": ("bench_imaging",
                "Patch stitching (index_add vs per-particle loop) and Dice-Focal vs cross-entropy."),
}


class _LazyBenchGroup(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(BENCHES)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in BENCHES:
            hint = closest(name, BENCHES)
            if hint:
                ctx.fail(f"no benchmark '{name}'. Did you mean '{hint}'?")
            return None
        return with_global_options(importlib.import_module(f"lesscli.cli.{BENCHES[name][0]}").cli)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(n, BENCHES[n][1]) for n in self.list_commands(ctx)]
        if rows:
            with formatter.section("Benchmarks"):
                formatter.write_dl(rows)


@click.group("bench", cls=_LazyBenchGroup)
def cli() -> None:
    """Measure what accuracy costs in time; results are JSON lines (table on a terminal)."""
