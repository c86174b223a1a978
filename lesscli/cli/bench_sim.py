"""``less bench sim``: the contact accuracy-vs-time ladder (SIMULATION.md tiers and V1)."""

from __future__ import annotations

import os

import click

from lesscli.bench.sim import CHECKS, run
from lesscli.cli.common import checked_output, format_option

DEFAULT_SCENE = os.path.join("examples", "scenes", "poke.toml")


@click.command("sim")
@click.option("--quick", is_flag=True, help="Small phantom and coarse meshes (about a minute).")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None, callback=checked_output(),
              help="Also draw error vs time per step to this PNG.")
@click.option("--check", "checks", multiple=True, type=click.Choice(CHECKS),
              help="Run only these checks (repeatable; default all).")
@click.option("--scene", "scene_path", type=click.Path(), default=None,
              help=f"Scene timed by the 'pipeline' check (default {DEFAULT_SCENE} when it exists).")
@click.option("--cache-dir", type=click.Path(), default=None,
              help="Compliance cache (default: a fresh temporary one, so "
              "precompute is timed).")
@format_option()
def cli(quick: bool, plot_path: str | None, checks: tuple[str, ...], scene_path: str | None,
        cache_dir: str | None, fmt: str | None) -> None:
    """Each contact tier's error against closed forms / the finest FEM, and its time per step.

    Columns: check, tier, mesh_mm, error (relative), ms_per_step, precompute_s, and for the scan
    check the seconds per 100-trajectory scan and the speed-up of tier 0 over tier 2.
    """
    from lesscli.io.records import emit_records

    if scene_path is None and os.path.exists(DEFAULT_SCENE):
        scene_path = DEFAULT_SCENE
    rows = []

    def collect():
        for row in run(quick=quick, cache_dir=cache_dir, scene_path=scene_path, checks=checks or CHECKS):
            rows.append(row)
            yield row

    emit_records(collect(), fmt)
    if plot_path:
        from lesscli.plots.sweeps import ladder_figure

        ladder_figure(rows, plot_path)
