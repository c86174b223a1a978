"""What the training commands (``pretrain``, ``image fit``) share: their options, their settings resolved
and checked (a bad value on the command line is a usage error before anything is read), and the run
(:mod:`lesscli.train.run`) with the command's progress bars and summary."""

from __future__ import annotations

import click

from lesscli.cli.common import STATE, config_resolved, emit_summary, progress, set_options, threads_option


def training_options(default_epochs: int | str, tables: str, set_example: str):
    """The options every training command shares (``--epochs`` ... ``--resume``); None = not given.

    The command receives them as keyword arguments ``epochs, batch_size, lr, seed, device,
    config_path, overrides, resume, tensorboard, threads`` (collect them with ``**train_opts``).
    """
    options = [
        click.option("--epochs", type=int, default=None, help=f"Epochs.  [default: {default_epochs}]"),
        click.option("--batch-size", type=int, default=None, help="Scans per batch.  [default: 2]"),
        click.option("--lr", type=float, default=None,
                     help="Adam learning rate (cosine decay).  [default: 1e-4]"),
        click.option("--seed", type=int, default=None,
                     help="Seed for initialisation and sampling.  [default: 0]"),
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
        flag = "--set" if _set_names(overrides, exc.key) else {**LOOP_FLAGS,
                                                               **(flags or {})}.get(exc.key, "--set")
        raise click.BadParameter(f"{exc.value!r}: {exc.key} must be {exc.need}",
                                 param_hint=f"'{flag}'") from None
    config_resolved(to_dict(cfg))
    return cfg


def _set_names(overrides, key: str) -> bool:
    """Whether one of the ``--set`` pairs sets ``key`` (``section.field``, or the bare field)."""
    for item in overrides:
        name = item.partition("=")[0].strip()
        if name in (key, key.split(".")[1]):
            return True
    return False


def train_and_emit(train_fn, data: str, val_path: str | None, cfg, output: str, fmt: str | None,
                   train_opts: dict) -> None:
    """Run ``train_fn`` as :func:`lesscli.train.run.run_training` does, with this command's bars (batch bars
    with -v) and shared options, and emit the summary record on rank 0 (:func:`emit_summary`)."""
    from lesscli.train.run import run_training

    summary = run_training(train_fn, data, val_path, cfg, output, progress=progress,
                           batch_progress=progress if STATE.verbose else None,
                           tensorboard=train_opts["tensorboard"], threads=train_opts["threads"],
                           resume=train_opts["resume"])
    if summary is not None:
        emit_summary([summary], output, fmt)
