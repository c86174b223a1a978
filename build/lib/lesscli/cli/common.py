"""Shared CLI plumbing: verbosity, logging, progress bars, common options, name suggestions."""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterable
from dataclasses import dataclass

import click

LOG = logging.getLogger("less")


@dataclass
class _State:
    verbose: int = 0
    quiet: bool = False


STATE = _State()


def configure(verbose: int = 0, quiet: bool = False) -> None:
    """Set up stderr logging for this process from ``-v``/``-q``."""
    STATE.verbose, STATE.quiet = verbose, quiet
    level = logging.ERROR if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    if verbose == 0 and not quiet:
        level = logging.WARNING
    for old in list(LOG.handlers):  # in-process reruns (tests) must log to the current stderr
        LOG.removeHandler(old)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("less: %(message)s"))
    LOG.addHandler(handler)
    LOG.propagate = False
    LOG.setLevel(level)


def progress(iterable: Iterable | None = None, **kwargs):
    """A tqdm progress bar on stderr, silent with ``-q`` (and when stderr is not a terminal and -v is off)."""
    from tqdm import tqdm

    disable = STATE.quiet or (not sys.stderr.isatty() and STATE.verbose == 0)
    return tqdm(iterable, file=sys.stderr, disable=disable, dynamic_ncols=True, **kwargs)


def format_option(func):
    """``--format jsonl|json|table|markdown`` (default: table on a terminal, JSON lines otherwise)."""
    return click.option(
        "--format",
        "fmt",
        type=click.Choice(["jsonl", "json", "table", "markdown"]),
        default=None,
        help="Record format on stdout (default: table on a terminal, else JSON lines).",
    )(func)


def check_known(names: Iterable[str], known, what: str, option: str) -> None:
    """A usage error (exit 2) for the first of ``names`` not in ``known``, with the nearest known name as a
    hint: "unknown metric 'com_error_3d'; did you mean 'com_error_mm_3d'?"."""
    from lesscli.errors import closest

    for name in names:
        if name not in known:
            hint = closest(name, known)
            raise click.BadParameter(f"unknown {what} '{name}'" + (f"; did you mean '{hint}'?" if hint else ""),
                                     param_hint=option)


def series_option(func):
    """``--series NUMBER|UID``: the series of a DICOM folder holding several (``mri-label``, ``info``)."""
    return click.option("--series", default=None, metavar="NUMBER|UID",
                        help="The series to read from a DICOM folder holding several (its SeriesNumber or "
                             "SeriesInstanceUID).")(func)


def deprecated(old: str, new: str) -> None:
    """The one stderr line for a spelling that still works in this release and goes in the next."""
    LOG.warning("%s is deprecated and goes in the next release; use %s", old, new)


def renamed_option(old: str, *decls: str, **attrs):
    """A click option spelled ``decls`` that still accepts its old spelling ``old`` for one release.

    The old spelling is a hidden option of the same type; given on the command line it prints one
    deprecation line on stderr and its value stands in for the new option's default (the new spelling
    wins when both are given). The new option's own callback, if any, sees the value either way.
    """
    new = click.Option(decls, **attrs)
    spelled = "/".join(new.opts)
    key = ("renamed", new.name)
    callback = attrs.pop("callback", None)

    def take_old(ctx: click.Context, param: click.Parameter, value):
        if value is not None and value != ():
            deprecated(old, spelled)
            ctx.meta[key] = value
        return value

    def take_new(ctx: click.Context, param: click.Parameter, value):
        from click.core import ParameterSource

        if key in ctx.meta and ctx.get_parameter_source(param.name) in (ParameterSource.DEFAULT, None):
            value = ctx.meta[key]
        return callback(ctx, param, value) if callback else value

    alias = click.option(old, "_old_" + new.name, hidden=True, expose_value=False, default=None, type=new.type,
                         multiple=new.multiple, callback=take_old, help=f"Old spelling of {spelled}.")
    current = click.option(*decls, callback=take_new, **attrs)

    def decorate(func):
        return alias(current(func))
    return decorate


def orientation_list(text: str, option: str = "--orientations") -> list[int]:
    """``'0-7'`` or ``'0,2,4'`` (ranges and lists mix: ``'0-2,6'``) -> orientations k in 0..7, in order.

    Raises:
        click.BadParameter: on text that does not parse or an orientation outside 0..7.
    """
    out: list[int] = []
    try:
        for part in text.split(","):
            first, _, last = part.partition("-")
            span = range(int(first), int(last or first) + 1)
            if not span:
                raise ValueError(part)
            out.extend(span)
    except ValueError:
        raise click.BadParameter(f"'{text}': expected e.g. 0-7 or 0,2,4", param_hint=option) from None
    if not out or any(not 0 <= k <= 7 for k in out):
        raise click.BadParameter(f"'{text}': orientations are 0..7 (45 degrees each)", param_hint=option)
    return out


def orientations_option(default: str = "0-7", help: str = "Orientations k (x 45 deg), e.g. 0-7 or 0,2,4."):
    """``--orientations`` in the one syntax every command shares (see :func:`orientation_list`)."""
    return click.option("--orientations", default=default, show_default=True, metavar="LIST", help=help,
                        callback=lambda ctx, param, value: orientation_list(value, "--orientations"))


def threads_option(help: str = "CPU threads for torch and BLAS (default: chosen from the free cores)."):
    """``--threads N``: overrides the thread policy (lesscli.threads) on every command that does torch work."""
    return click.option("--threads", type=click.IntRange(1), default=None, metavar="N", help=help)


def realtime_option():
    """``--realtime``: latency-bound commands run under the real-time FIFO policy (lesscli.threads.set_realtime)."""
    return click.option("--realtime", is_flag=True,
                        help="Run under the real-time FIFO scheduling policy, so that busy processes do not delay "
                             "updates (Linux; needs root, CAP_SYS_NICE or `ulimit -r`).")


def labelling_options(func):
    """``--threshold``, ``--min-volume-mm3`` and ``--smooth-mm``: the labelling rule of every command that
    labels images (``image predict``, ``stream``, ``guide``); each defaults to the model's (see
    infer.predict.labelling_rule)."""
    func = click.option("--smooth-mm", "smooth_mm", type=click.FloatRange(min=0), default=None,
                        help="Label from probabilities smoothed across each slice by a Gaussian of this standard "
                             "deviation (mm; 0: none). Default: the model's, chosen on --val by image fit; else 0.")(func)
    func = click.option("--min-volume-mm3", "min_volume_mm3", type=click.FloatRange(min=0), default=None,
                        help="Drop inclusion regions smaller than this volume (mm^3; 0: keep all). Default: the "
                             "model's, chosen on --val by image fit; else 0.")(func)
    return click.option("--threshold", type=click.FloatRange(0, 1), default=None,
                        help="Pillar/inclusion only above this probability (hand-held setting: 0.8). Default: the "
                             "model's, chosen on --val by image fit; else argmax.")(func)


def device_option(help: str = "auto (CUDA when available, else CPU), cpu, cuda or cuda:N."):
    """``--device``, ``auto`` by default in every command."""
    return click.option("--device", default="auto", show_default=True, help=help)


def checked_output(folder: bool = False):
    """A click callback that checks an output path (see lesscli.io.atomic.check_output) at parse time,
    before the command does any work."""
    def callback(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
        from lesscli.io.atomic import check_output

        if value is not None:
            check_output(value, folder=folder, option=param.opts[0] if param.opts else "-o")
        return value
    return callback


def output_option(required: bool = True, help: str = "Output file ('-' for stdout).", folder: bool = False):
    """``-o/--output PATH``, checked before the command starts (``folder``: the output is a folder)."""
    return click.option("-o", "--output", "output", type=click.Path(), required=required, help=help,
                        callback=checked_output(folder))


_PRINT_CONFIG = "less.print_config"


def set_options(help: str):
    """``--set KEY=VALUE`` (repeatable, keyword ``overrides``; syntax in lesscli.io.overrides) and with it
    ``--print-config``: the command hands its resolved configuration to :func:`config_resolved`, which
    then prints it as TOML on stdout and exits 0 before any work is done."""
    def remember(ctx: click.Context, param: click.Parameter, value: bool) -> bool:
        ctx.meta[_PRINT_CONFIG] = value
        return value

    set_option = click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=help)
    print_option = click.option("--print-config", is_flag=True, expose_value=False, callback=remember,
                                help="Print the resolved settings (defaults < file < options < --set) "
                                     "as TOML and exit without doing the work.")
    return lambda func: set_option(print_option(func))


def print_config_requested() -> bool:
    """Whether this command was given ``--print-config``."""
    return bool(click.get_current_context().meta.get(_PRINT_CONFIG))


def config_resolved(doc: dict) -> None:
    """Called by a command once its configuration ``doc`` (a nested dict) is resolved: with ``--print-config``
    print it as TOML and exit 0, else return."""
    if print_config_requested():
        from lesscli.io.toml_files import dump_toml

        click.echo(dump_toml(doc), nl=False)
        raise click.exceptions.Exit(0)


def training_options(default_epochs: int, tables: str, set_example: str):
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


def training_config(cls, explicit: dict, train_opts: dict):
    """``cls`` config from defaults < ``--config`` < ``explicit`` and the shared options < ``--set`` (printed
    and the command ended here with ``--print-config``)."""
    from lesscli.train.config import load_config, to_dict

    loop = {f"train.{k}": train_opts[k] for k in ("epochs", "batch_size", "lr", "seed", "device")}
    cfg = load_config(cls, train_opts["config_path"], train_opts["overrides"], {**explicit, **loop})
    config_resolved(to_dict(cfg))
    return cfg


def run_training(train_fn, what: str, data: str, val_path: str | None, cfg, output: str, fmt: str | None,
                 tensorboard: str | None = None, threads: int | None = None) -> None:
    """Load DATA and --val, train under torchrun/DDP when launched so, and print the summary on rank 0.

    ``train_fn(train, val, env=, history=, watch=, names=)`` trains and returns a summary record. Rank
    0 shows the epoch bar (batch bars with -v) and writes the TensorBoard scalars (``tensorboard``);
    a missing tensorboard package is an error before anything is loaded. Each process takes its
    share of the free cores (``threads`` overrides; lesscli.threads), recorded in the summary.
    """
    import os

    from lesscli.io.records import emit_records
    from lesscli.io.scans import append_history
    from lesscli.threads import apply_threads
    from lesscli.train import distributed
    from lesscli.train.watch import TensorBoardScalars, Watch, require_tensorboard

    if tensorboard:
        require_tensorboard(tensorboard)
    n_threads = apply_threads("throughput", override=threads, jobs=int(os.environ.get("LOCAL_WORLD_SIZE", "1")))
    train = training_scans(data)
    val = training_scans(val_path) if val_path else None
    env = distributed.setup(cfg.train.device)
    board = TensorBoardScalars(tensorboard) if tensorboard and env.is_main else None
    watch = Watch(progress, progress if STATE.verbose else None, [board] if board else []) if env.is_main else Watch()
    try:
        history = append_history({}, seed=cfg.train.seed)["history"]
        summary = train_fn(train, val, env=env, history=history, names=(data, val_path or ""), watch=watch)
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


def training_scans(path: str):
    """Load a scan set to learn from: untouched scans (no steps) teach nothing and are left out with a
    warning; a set with no touches at all is a DataError."""
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
    return scans


def comma_list(text: str, cast: type, what: str) -> tuple:
    """``'1,2.5'`` -> values of type ``cast``; click.BadParameter naming ``what`` when one does not parse."""
    try:
        return tuple(cast(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"'{text}' is not a comma-separated list of {cast.__name__} values",
                                 param_hint=what) from None


def seed_option(default: int = 0):
    return click.option("--seed", type=int, default=default, show_default=True, help="Random seed.")


def parse_shard(text: str | None) -> tuple[int, int]:
    """Parse ``i/n`` (0-based shard i of n); None means the whole job (0/1)."""
    if not text:
        return 0, 1
    try:
        i, n = (int(p) for p in text.split("/"))
    except ValueError:
        raise click.BadParameter(f"'{text}' is not of the form i/n (e.g. 0/4)", param_hint="--shard")
    if n < 1 or not 0 <= i < n:
        raise click.BadParameter(f"'{text}': need 0 <= i < n", param_hint="--shard")
    return i, n
