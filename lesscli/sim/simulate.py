"""Scene -> scan set: one scan per (insert, orientation), run through the compiled pipeline.

Scans are numbered in scene order (inserts, then orientations). ``shard=(i, n)`` takes the i-th of n
contiguous blocks of that list; since every random stream is keyed by the global scan index, a scan
is byte-identical whether it is computed alone, in a shard, or by any worker of a parallel run.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import multiprocessing
import signal
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lesscli.errors import DataError
from lesscli.io.labels import LabelVolume
from lesscli.io.scans import TRAJ_ATTRS, ScanSet, default_meta
from lesscli.phantom.geometry import Phantom
from lesscli.sim.core import FLAG_OUTSIDE_VALIDITY, get_model
from lesscli.sim.pipeline import compile_pipeline, initial_state, run_stages
from lesscli.sim.scene import Scene, label_spacing_for


@dataclass
class ScanJob:
    """One scan to simulate: global index, insert (orientation 0) and orientation k."""

    index: int
    phantom: Phantom
    orientation: int


@dataclass
class ScanPart:
    """The arrays of one simulated scan (picklable, returned by workers)."""

    insert: str
    orientation: int
    pose: np.ndarray
    force: np.ndarray
    time_s: np.ndarray
    lengths: np.ndarray
    attrs: dict
    label: LabelVolume
    force_units: str
    info: dict


def scan_jobs(scene: Scene, shard: tuple[int, int] = (0, 1)) -> list[ScanJob]:
    """The scene's scans (inserts x orientations), restricted to shard i of n (contiguous blocks)."""
    jobs = [ScanJob(len(scene.orientations) * i + j, p, k) for i, p in enumerate(scene.phantoms)
            for j, k in enumerate(scene.orientations)]
    i, n = shard
    bounds = np.linspace(0, len(jobs), n + 1).round().astype(int)
    return jobs[bounds[i]:bounds[i + 1]]


def simulate_scan(scene: Scene, job: ScanJob, stages=None) -> ScanPart:
    """Run the pipeline for one scan and collect its arrays (trajectories dropped per contact.on_invalid)."""
    stages = compile_pipeline(scene) if stages is None else stages
    state = run_stages(stages, initial_state(scene, job.index, job.phantom, job.orientation))
    lengths = np.diff(state.offsets)
    keep = np.ones(len(lengths), dtype=bool)
    if scene.contact["on_invalid"] == "drop":
        bad = (state.flags & FLAG_OUTSIDE_VALIDITY) != 0
        keep = np.add.reduceat(bad.astype(np.int64), state.offsets[:-1]) == 0 if len(bad) else keep
    steps = np.repeat(keep, lengths)
    attrs = {key: np.array([a.get(key, "" if kind is str else np.nan) for a,
                            k in zip(state.traj_attrs, keep) if k])
             .astype(kind) for key, kind in TRAJ_ATTRS.items()}
    phantom = job.phantom.rotated(job.orientation)
    label = phantom.label_volume(scene.labels["shape"], label_spacing_for(phantom, scene.labels))
    info = {**state.info, "dropped_trajectories": int((~keep).sum())}
    return ScanPart(state.insert, job.orientation, state.pose_out[steps].astype(np.float32),
                    state.force[steps].astype(np.float32), state.time_s[steps], lengths[keep], attrs, label,
                    state.force_units, info)


def _worker(args: tuple[Scene, ScanJob]) -> ScanPart:
    return simulate_scan(*args)


def contact_phantoms(scene: Scene, todo: list[ScanJob]) -> list[Phantom]:
    """The distinct phantoms the contact tier will see (after the phantom-slot effects), in first-use
    order."""
    early = tuple(s for s in compile_pipeline(scene) if s.slot == "phantom")
    seen: dict[str, Phantom] = {}
    for job in todo:
        phantom = run_stages(early, initial_state(scene, job.index, job.phantom, job.orientation)).phantom
        seen.setdefault(phantom.content_hash(), phantom)
    return list(seen.values())


def _prepare_worker(args: tuple[Scene, Phantom]) -> None:
    """Warm the tier's on-disk cache for one phantom, so parallel scans do not repeat the precompute."""
    scene, phantom = args
    get_model(scene.contact["tier"], phantom, scene.sensor, scene.contact["params"],
              scene.contact["cache_dir"])


def simulate(scene: Scene, jobs: int = 1, shard: tuple[int, int] = (0, 1),
             progress: Callable | None = None) -> ScanSet:
    """Simulate the scene (or one shard of it) into a ScanSet.

    Args:
        scene: a validated scene.
        jobs: worker processes (1 = in this process).
        shard: (i, n), 0-based shard i of n.
        progress: optional wrapper ``progress(iterable, total=...)`` (e.g. a tqdm factory).
    """
    todo = scan_jobs(scene, shard)
    if not todo:
        raise DataError(f"{scene.source}: shard {shard[0]}/{shard[1]} holds no scans "
                        f"(the scene has {len(scene.phantoms) * len(scene.orientations)})")
    wrap = progress or (lambda it, total: it)
    if jobs <= 1:
        stages = compile_pipeline(scene)
        parts = [simulate_scan(scene, job, stages) for job in wrap(todo, total=len(todo))]
    else:
        with worker_pool(jobs) as pool:
            pool.map(_prepare_worker, [(scene, p) for p in contact_phantoms(scene, todo)])
            parts = list(wrap(pool.imap(_worker, [(scene, job) for job in todo]), total=len(todo)))
    return assemble(scene, parts, shard)


def _ignore_interrupt() -> None:
    """Worker start: Ctrl-C (SIGINT, sent to the whole process group) is the parent's to handle; the
    workers are stopped by it, so they neither print a traceback nor die half-way through a reply."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@contextlib.contextmanager
def worker_pool(jobs: int):
    """A pool of ``jobs`` worker processes (forked where the platform can) that ignore Ctrl-C. On any
    exception in the block, Ctrl-C included, the workers are terminated at once, not waited for, so
    an interrupted run ends promptly (exit 130) instead of hanging on a half-finished pool."""
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    blocked = hasattr(signal, "pthread_sigmask")
    if blocked:            # a Ctrl-C while the workers start waits until they ignore it, then reaches us
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        pool = ctx.Pool(jobs, initializer=_ignore_interrupt if blocked else None)
    finally:
        if blocked:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    try:
        yield pool
    except BaseException:
        pool.terminate()
        pool.join()
        raise
    pool.close()
    pool.join()


def scene_meta(scene: Scene, parts: list[ScanPart], shard: tuple[int, int]) -> dict:
    """``meta['simulation']``: what produced the data (scene, tier, effects, seed, shard, counters)."""
    doc_hash = hashlib.sha1(json.dumps(scene.doc, sort_keys=True, default=str).encode()).hexdigest()
    return {"scene": scene.name, "scene_file": scene.source, "scene_sha1": doc_hash, "seed": scene.seed,
            "tier": scene.contact["tier"], "contact_params": scene.contact["params"],
            "motion": scene.motion["kind"], "effects": scene.effects, "shard": f"{shard[0]}/{shard[1]}",
            "flagged_steps": int(sum(p.info.get("flagged_steps", 0) for p in parts)),
            "dropped_trajectories": int(sum(p.info.get("dropped_trajectories", 0) for p in parts))}


def assemble(scene: Scene, parts: list[ScanPart], shard: tuple[int, int] = (0, 1)) -> ScanSet:
    """Concatenate scan parts into one ScanSet (identical label volumes stored once)."""
    labels, index, scan_label = [], {}, []
    for part in parts:
        key = part.label.content_hash()
        if key not in index:
            index[key] = len(labels)
            labels.append(part.label)
        scan_label.append(index[key])
    lengths = np.concatenate([p.lengths for p in parts]).astype(np.int64)
    units = {p.force_units for p in parts}
    meta = default_meta(scene.sensor, force_units=units.pop(),
                        sample_rate_hz=float(scene.motion["params"].get("rate_hz", 100.0)),
                        simulation=scene_meta(scene, parts, shard))
    return ScanSet(
        pose=np.concatenate([p.pose for p in parts]), force=np.concatenate([p.force for p in parts]),
        time_s=np.concatenate([p.time_s for p in parts]),
        traj_offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        traj_scan=np.repeat(np.arange(len(parts)), [len(p.lengths) for p in parts]).astype(np.int64),
        scan_insert=np.array([p.insert for p in parts]),
        scan_orientation=np.array([p.orientation for p in parts]), scan_label=np.array(scan_label, np.int64),
        labels=labels, traj_attrs={k: np.concatenate([p.attrs[k] for p in parts]) for k in TRAJ_ATTRS},
        meta=meta)
