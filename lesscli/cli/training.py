"""What the training commands (``pretrain``, ``image fit``) share: their options, their settings resolved
and checked (a bad value on the command line is a usage error before anything is read), and the run
itself (data, torchrun, threads, the epoch bar, the summary; a full disk cleans up)."""

from __future__ import annotations

import click

from lesscli.cli.common import LOG, STATE, config_resolved, progress, set_options, threads_option


def training_options(default_epochs: int | str, tables: str, set_example: str):
    """The options every training command shares (``--epochs`` ... ``--resume``); None = not given.

    The command receives them as keyword arguments ``epochs, batch_size, lr, seed, device,
    config_path, overrides, resume, tensorboard, threads`` (collect them with ``**train_opts``).
    """
    options = [
        click.option("--epochs", type=int, default=None, help=f"Epochs.  [default: {default_epochs}]"),
        click.option("--batch-size", type=int, default=None, help="Scans per batch.  [default: 2]"),
        click.option("--lr", type=float, default=None, help="Adam learning rate (cosine decay).  [default: 1e-4]"),
        click.option("--seed", type=int, default=None, help="Seed for initialisation and sampling.  [default: 0]"),
        click.option("--device", default=None, help="auto, cpu, cuda or cuda:N.  [default: auto]"),
        click.option("--config", "config_path", type=click.Path(), default=None,
                     help=f"TOML file with {tables} tables."),
        set_options(f"Override a setting, e.g. {set_example} (repeatable)."),
        click.option("--resume", is_flag=True, help="Continue from <stem>.last.pt with the same settings."),
        threads_option(),
        click.option("--tensorboard", default=None, type=click.Path(file_okay=False), metavar="DIR",
                     help="Also write each epoch's losses and scores as TensorBoard scalars into DIR "
                          "(needs the tensorboard extra)."),
    ]

    def decorate(func):
        for option in reversed(options):
            func = option(func)
        return func
    return decorate


LOOP_FLAGS = {"train.epochs": "--epochs", "train.batch_size": "--batch-size", "train.lr": "--lr",
              "train.seed": "--seed", "train.device": "--device"}


def training_config(cls, explicit: dict, train_opts: dict, check=None, flags: dict | None = None):
    """``cls`` config from defaults < ``--config`` < ``explicit`` and the shared options < ``--set``, checked
    by ``check`` (raising lesscli.train.config.SettingError), then printed and the command ended here with
    ``--print-config``.

    A bad value on the command line (an option, named by ``flags``: setting -> option, or ``--set``, and
    an unknown ``--set`` key) is a usage error (exit 2) before anything is read; one in the ``--config``
    file is a data error naming the file (exit 1).
    """
    from lesscli.errors import DataError
    from lesscli.train.config import SettingError, load_config, to_dict

    path, overrides = train_opts["config_path"], train_opts["overrides"]
    loop = {key: train_opts[key.split(".")[1]] for key in LOOP_FLAGS}
    from_file = load_config(cls, path)                      # the file's own errors: exit 1, naming it
    try:
        cfg = load_config(cls, path, overrides, {**explicit, **loop})
    except DataError as exc:
        raise click.UsageError(str(exc)) from None
    try:
        if check is not None:
            check(cfg)
    except SettingError as exc:
        section, name = exc.key.split(".")
        if getattr(getattr(from_file, section), name) == exc.value and path:
            raise DataError(f"{path}: {exc}") from None
        flag = "--set" if _set_names(overrides, exc.key) else {**LOOP_FLAGS, **(flags or {})}.get(exc.key, "--set")
        raise click.BadParameter(f"{exc.value!r}: {exc.key} must be {exc.need}", param_hint=f"'{flag}'") from None
    config_resolved(to_dict(cfg))
    return cfg


def _set_names(overrides, key: str) -> bool:
    """Whether one of the ``--set`` pairs sets ``key`` (``section.field``, or the bare field)."""
    for item in overrides:
        name = item.partition("=")[0].strip()
        if name in (key, key.split(".")[1]):
            return True
    return False


def run_training(train_fn, what: str, data: str, val_path: str | None, cfg, output: str, fmt: str | None,
                 tensorboard: str | None = None, threads: int | str | None = None, resume: bool = False) -> None:
    """Load DATA and --val, train under torchrun/DDP when launched so, and print the summary on rank 0.

    ``train_fn(train, val, env=, history=, watch=, names=)`` trains and returns a summary record. Rank
    0 shows the epoch bar (batch bars with -v) and writes the TensorBoard scalars (``tensorboard``);
    a missing tensorboard package is an error before anything is loaded. Each process takes its
    share of the cores (``threads`` overrides; lesscli.threads), recorded in the summary. When an
    output cannot be written (a full disk, its folder gone), a fresh run (not ``resume``) removes what
    it wrote (``output``, ``<stem>.last.pt``, ``<stem>.log.jsonl``) and stops with one line.
    """
    import os

    from lesscli.errors import OutputError
    from lesscli.io.records import emit_records
    from lesscli.io.scans import append_history
    from lesscli.threads import apply_threads, deterministic_kernels
    from lesscli.train import distributed
    from lesscli.train.watch import TensorBoardScalars, Watch, require_tensorboard

    if tensorboard:
        require_tensorboard(tensorboard)
    n_threads = apply_threads("throughput", override=threads, jobs=int(os.environ.get("LOCAL_WORLD_SIZE", "1")))
    train = training_scans(data)
    val = training_scans(val_path) if val_path else None
    if val is not None:
        from lesscli.data.compat import check_match, signature

        check_match(signature(train), val, data, val_path)
    env = distributed.setup(cfg.train.device)
    deterministic_kernels(env.device)                   # the same bytes on a rerun (lesscli.threads)
    board = TensorBoardScalars(tensorboard) if tensorboard and env.is_main else None
    watch = Watch(progress, progress if STATE.verbose else None, [board] if board else []) if env.is_main else Watch()
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
        return
    summary["threads"] = n_threads
    if output == "-":
        LOG.warning("%s summary: %s", what, summary)
    else:
        emit_records([summary], fmt)


def remove_run_files(output: str) -> None:
    """Remove a training run's files: ``output``, ``<stem>.last.pt`` and ``<stem>.log.jsonl`` (those there)."""
    import contextlib
    import os

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
