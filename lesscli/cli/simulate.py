"""``less simulate SCENE.toml -o OUT.npz``: palpation scans from a scene file."""

from __future__ import annotations

import click

from lesscli.cli.common import ThreadsType, format_option, output_option, parse_shard, set_options


@click.command("simulate")
@click.argument("scene_path", type=click.Path(), metavar="SCENE.toml")
@output_option(help="Output scan set (.npz, '-' for stdout).", lock=True)
@set_options("Override a scene value, e.g. --set motion.n_traj=10 --set contact.tier=winkler.")
@click.option("--seed", type=int, default=None, help="Override the scene's seed.")
@click.option("--jobs", type=ThreadsType(), default=None, metavar="N|auto",
              help="Worker processes (over scans); default: the usable cores (at most one a scan); 'auto': "
                   "the free cores (usable cores minus the load). The output is the same for any N.")
@click.option("--shard", default=None, metavar="I/N",
              help="Simulate only shard I of N (0-based, contiguous).")
@format_option()
def cli(scene_path: str, output: str, overrides: tuple[str, ...], seed: int | None, jobs: int | str | None,
        shard: str | None, fmt: str | None) -> None:
    """Simulate the scans of SCENE.toml into a less.scans/1 scan set with label volumes.

    SCENE.toml is a scene file or the name of a scene shipped with the package: quick (the tutorial's
    and the demo's randomised training family), poke, primitive, handheld, multiple, large, demo.

    One scan per insert and orientation; the output is byte-identical for a given seed, whatever
    --jobs is (default: the usable cores, at most one worker a scan), and the shards of --shard i/n
    concatenate to the full set. One summary record (scans,
    trajectories, steps, jobs, threads, seconds, output) goes to stdout (to stderr with -o -).

    Example: less simulate demo -o demo.npz --set motion.n_traj=20
    """
    import time

    from lesscli.cli.common import config_resolved, emit_summary, progress
    from lesscli.io.scans import append_history, save_scans
    from lesscli.scenes import resolve
    from lesscli.sim.scene import load_scene, scene_document
    from lesscli.sim.simulate import scan_jobs, simulate
    from lesscli.threads import AUTO, apply_threads, free_cores, load_average, usable_cores

    t0 = time.perf_counter()
    i_n = parse_shard(shard)
    scene = load_scene(resolve(scene_path), overrides, options={"seed": seed})
    config_resolved(scene_document(scene))
    adaptive = jobs == AUTO
    load = load_average() if adaptive else None    # read the machine once, if asked
    wanted = free_cores(usable_cores(), load) if adaptive else (jobs or usable_cores())
    jobs = min(wanted, max(1, len(scan_jobs(scene, i_n))))
    threads = apply_threads("throughput", jobs=jobs, torch_too=False, load=load,   # per worker: --jobs splits
                            override=AUTO if adaptive else None)                   # the cores
    scans = simulate(scene, jobs=jobs, shard=i_n,
                     progress=lambda it, total: progress(it, total=total, desc="scans", unit="scan"))
    scans.meta = append_history(scans.meta, seed=scene.seed)
    save_scans(output, scans)
    summary = {"output": output, "scans": scans.n_scans, "trajectories": scans.n_traj, "steps": scans.n_steps,
               "seed": scene.seed, "shard": f"{i_n[0]}/{i_n[1]}", "jobs": jobs, "threads": threads,
               "seconds": round(time.perf_counter() - t0, 2)}
    emit_summary([summary], output, fmt)
