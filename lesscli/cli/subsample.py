"""``less subsample FILE``: every N-th step, K trajectories per scan, a maximum length."""

from __future__ import annotations

import click

from lesscli.cli.common import LOG, output_option, seed_option


@click.command("subsample")
@click.argument("path", type=click.Path(), metavar="FILE")
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True,
              help="Keep every N-th step within each trajectory (50 for pokes, 10 for primitives).")
@click.option("--trajectories", type=click.IntRange(min=1), default=None,
              help="Keep K trajectories per scan, drawn with --seed (default: all).")
@click.option("--max-length", type=click.IntRange(min=1), default=None,
              help="Truncate each trajectory to L steps after subsampling.")
@seed_option()
@output_option()
def cli(path: str, every: int, trajectories: int | None, max_length: int | None, seed: int,
        output: str) -> None:
    """Subsample a scan set (FILE: .npz, a folder of shards, or '-').

    Example: less subsample raw.npz --every 50 --trajectories 100 --seed 0 -o poke.npz
    """
    import numpy as np

    from lesscli.data.ops import subsample
    from lesscli.io.scans import append_history, load_scans, save_scans

    scans = load_scans(path)
    out = subsample(scans, every, trajectories, max_length, np.random.default_rng(seed))
    out.meta = append_history(out.meta, seed=seed)
    save_scans(output, out)
    LOG.info("%s: %d scans, %d trajectories, %d steps (from %d steps)", output, out.n_scans, out.n_traj,
             out.n_steps, scans.n_steps)
