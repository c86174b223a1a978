"""Dataset operations on scan sets: subsample, split (by insert or by scan), per-split summaries."""

from __future__ import annotations

import numpy as np

from lesscli.errors import DataError
from lesscli.io.scans import ScanSet

SPLIT_NAMES = ("train", "val", "test")


def step_index_in_trajectory(scans: ScanSet) -> np.ndarray:
    """(N,) position of each step within its trajectory (0 at each trajectory's first step)."""
    lengths = scans.traj_lengths()
    return np.arange(scans.n_steps) - np.repeat(scans.traj_offsets[:-1], lengths)


def pick_trajectories(scans: ScanSet, per_scan: int, rng: np.random.Generator) -> np.ndarray:
    """(R,) bool: ``per_scan`` trajectories drawn without replacement in each scan (all if fewer).

    The draw for each scan uses ``rng`` in scan order, so the result depends only on the seed and
    the input; kept trajectories stay in their recorded order.
    """
    keep = np.zeros(scans.n_traj, bool)
    toff = scans.scan_traj_offsets()
    for s in range(scans.n_scans):
        count = int(toff[s + 1] - toff[s])
        chosen = (rng.choice(count, size=min(per_scan, count), replace=False) if count
                  else np.zeros(0, np.int64))
        keep[toff[s] + chosen] = True
    return keep


def subsample(scans: ScanSet, every: int = 1, trajectories: int | None = None, max_length: int | None = None,
              rng: np.random.Generator | None = None) -> ScanSet:
    """Keep ``trajectories`` per scan (seeded), then every ``every``-th step of each, then the first
    ``max_length``.

    Args:
        scans: input scan set.
        every: keep steps 0, every, 2 every, ... of each trajectory (1:50 for pokes, 1:10 for primitives).
        trajectories: trajectories kept per scan (None: all), drawn with ``rng``.
        max_length: trajectories are truncated to this many steps after subsampling (None: no limit).
        rng: random generator for the trajectory draw (required with ``trajectories``).

    Returns:
        A new ScanSet; ``meta['sample_rate_hz']`` divided by ``every``. Scans keep their place even
        when they lose every trajectory.
    """
    if every < 1 or (trajectories is not None and trajectories < 1) or (max_length is not None
                                                                        and max_length < 1):
        raise ValueError("every, trajectories and max_length must be >= 1")
    out = scans
    if trajectories is not None:
        if rng is None:
            raise ValueError("choosing trajectories needs a random generator")
        out = out.select_trajectories(pick_trajectories(out, trajectories, rng))
    index = step_index_in_trajectory(out)
    keep = index % every == 0
    if max_length is not None:
        keep &= index // every < max_length
    out = out.select_steps(keep)
    rate = out.meta.get("sample_rate_hz")
    out.meta = {**out.meta, "sample_rate_hz": rate / every if isinstance(rate, (int, float)) else rate}
    return out


def _counts(n: int, test: float, val: float) -> tuple[int, int]:
    """Groups for test and val out of ``n``: rounded shares, at least one each when asked for."""
    n_test = max(1, round(test * n)) if test > 0 else 0
    n_val = max(1, round(val * n)) if val > 0 else 0
    return n_test, n_val


def split_groups(scans: ScanSet, by: str) -> tuple[list[str], np.ndarray]:
    """Group keys and (S,) group index per scan: by insert name, or each scan its own group."""
    if by == "insert":
        keys = sorted(set(scans.scan_insert.tolist()))
        lookup = {k: i for i, k in enumerate(keys)}
        return keys, np.array([lookup[k] for k in scans.scan_insert.tolist()], np.int64)
    if by == "scan":
        return [str(i) for i in range(scans.n_scans)], np.arange(scans.n_scans)
    raise ValueError(f"unknown split key '{by}' (insert or scan)")


def split(scans: ScanSet, by: str, test: float, val: float, rng: np.random.Generator,
          name: str = "scan set") -> dict[str, ScanSet]:
    """Split scans into train/val/test so that no group (insert, or scan) is in two splits.

    Groups are shuffled with ``rng`` and dealt: the first ``round(test * G)`` (>= 1 when test > 0)
    to test, the next ``round(val * G)`` (>= 1 when val > 0) to val, the rest to train. Scans keep
    their input order within a split. ``val`` is omitted from the result when ``val == 0``.

    Raises:
        DataError: too few groups to give every requested split at least one.
    """
    if not (0 <= test < 1 and 0 <= val < 1 and test + val < 1):
        raise ValueError("need 0 <= test, val and test + val < 1")
    keys, group_of_scan = split_groups(scans, by)
    n_test, n_val = _counts(len(keys), test, val)
    if n_test + n_val >= len(keys):
        raise DataError(f"{name}: {len(keys)} {by}(s) cannot fill train, "
                        f"{'val, ' if val else ''}test without sharing one (need at least "
                        f"{n_test + n_val + 1})")
    order = rng.permutation(len(keys))
    assign = np.empty(len(keys), np.int64)
    assign[order[:n_test]] = 2
    assign[order[n_test:n_test + n_val]] = 1
    assign[order[n_test + n_val:]] = 0
    split_of_scan = assign[group_of_scan]
    return {SPLIT_NAMES[k]: scans.select_scans(np.flatnonzero(split_of_scan == k))
            for k in (0, 1, 2) if k != 1 or val > 0}


def split_record(split_name: str, part: ScanSet, path: str) -> dict:
    """One summary row of a split: counts and the inserts it holds."""
    return {"split": split_name, "file": path, "scans": part.n_scans, "trajectories": part.n_traj,
            "steps": part.n_steps, "inserts": sorted(set(part.scan_insert.tolist()))}
