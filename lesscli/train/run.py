"""One training run as the training commands start it: the scans to learn from, torchrun/DDP, threads,
deterministic kernels, the epoch display, and on a failed write the files a fresh run wrote removed."""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable

from lesscli.train.watch import no_bar

LOG = logging.getLogger("less")


def run_training(train_fn: Callable, data: str, val_path: str | None, cfg, output: str, *,
                 progress: Callable = no_bar, batch_progress: Callable | None = None,
                 tensorboard: str | None = None, threads: int | str | None = None,
                 resume: bool = False) -> dict | None:
    """Load DATA and ``val_path``, train under torchrun/DDP when launched so; the summary on rank 0.

    ``train_fn(train, val, env=, history=, watch=, names=)`` trains and returns a summary record. Rank
    0 shows the epoch bar (``progress``; batch bars with ``batch_progress``) and writes the TensorBoard
    scalars (``tensorboard``); a missing tensorboard package is an error before anything is loaded. Each
    process takes its share of the cores (``threads`` overrides; lesscli.threads), recorded in the
    summary. When an output cannot be written (a full disk, its folder gone), a fresh run (not
    ``resume``) removes what it wrote (``output``, ``<stem>.last.pt``, ``<stem>.log.jsonl``) and re-raises.

    Returns:
        The summary record with its ``threads``, or None on ranks other than 0.
    """
    from lesscli.errors import OutputError
    from lesscli.io.scans import append_history
    from lesscli.threads import apply_threads, deterministic_kernels
    from lesscli.train import distributed
    from lesscli.train.watch import TensorBoardScalars, Watch, require_tensorboard

    if tensorboard:
        require_tensorboard(tensorboard)
    n_threads = apply_threads("throughput", override=threads,
                              jobs=int(os.environ.get("LOCAL_WORLD_SIZE", "1")))
    train = training_scans(data)
    val = training_scans(val_path) if val_path else None
    if val is not None:
        from lesscli.data.compat import check_match, signature

        check_match(signature(train), val, data, val_path)
    env = distributed.setup(cfg.train.device)
    deterministic_kernels(env.device)                   # the same bytes on a rerun (lesscli.threads)
    board = TensorBoardScalars(tensorboard) if tensorboard and env.is_main else None
    watch = Watch(progress, batch_progress, [board] if board else []) if env.is_main else Watch()
    try:
        history = append_history({}, seed=cfg.train.seed)["history"]
        summary = train_fn(train, val, env=env, history=history, names=(data, val_path or ""), watch=watch)
    except OutputError:
        if env.is_main and not resume and output != "-":
            remove_run_files(output)
        raise
    finally:
        if board:
            board.close()
        distributed.teardown(env)
    if not env.is_main:
        return None
    summary["threads"] = n_threads
    return summary


def remove_run_files(output: str) -> None:
    """Remove a training run's files: ``output``, ``<stem>.last.pt`` and ``<stem>.log.jsonl`` (those
    there)."""
    from lesscli.train.loop import side_paths

    for path in (output, *side_paths(output)):
        with contextlib.suppress(OSError):
            os.remove(path)


def training_scans(path: str):
    """Load a scan set to learn from, in its surface frame (lesscli.data.surface): untouched scans (no steps)
    teach nothing and are left out with a warning; a set with no touches at all is a DataError."""
    from lesscli.data.compat import prepare
    from lesscli.errors import DataError
    from lesscli.io.scans import load_scans

    scans = load_scans(path)
    touched = scans.touched_scans()
    if len(touched) < scans.n_scans:
        if not len(touched):
            raise DataError(f"{path}: no scan has any steps; there is nothing to learn from")
        LOG.warning("%s: %d of %d scans have no steps (untouched); training leaves them out",
                    path, scans.n_scans - len(touched), scans.n_scans)
        scans = scans.select_scans(touched)
    return prepare(scans, path)
