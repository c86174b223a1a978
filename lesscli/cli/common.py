"""Shared CLI plumbing: verbosity, logging, progress bars, summaries, name suggestions, shared options.

Each shared option is a factory, called where it decorates a command (``@format_option()``):
``format_option()`` ``--format jsonl|json|table|markdown`` of records on stdout;
``output_option()`` ``-o/--output PATH``, checked (and with ``lock`` held) before the command starts;
``seed_option()`` ``--seed``; ``device_option()`` ``--device auto|cpu|cuda|cuda:N``;
``threads_option()`` ``--threads N|auto`` (lesscli.threads); ``realtime_option()`` ``--realtime``;
``orientations_option()`` ``--orientations LIST`` (:func:`orientation_list`);
``labelling_options()`` ``--threshold``, ``--min-volume-mm3``, ``--smooth-mm``;
``series_option()`` ``--series`` of a DICOM folder; ``set_options(help)`` ``--set KEY=VALUE`` and
``--print-config``; ``renamed_option(old, ...)`` an option that still takes its old spelling for one
release. Every command also takes ``-v`` and ``-q`` after its name (:func:`with_global_options`).
"""

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
    verbose_given: int = 0      # -v counted by the group's option (those after the subcommand add to it)


STATE = _State()


def configure(verbose: int = 0, quiet: bool = False) -> None:
    """Set up stderr logging for this process from ``-v``/``-q``."""
    STATE.verbose, STATE.quiet, STATE.verbose_given = verbose, quiet, verbose
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


def _more_verbose(ctx: click.Context, param: click.Parameter, value: int) -> int:
    if value:
        configure(verbose=STATE.verbose_given + value, quiet=STATE.quiet)
    return value


def _quieter(ctx: click.Context, param: click.Parameter, value: bool) -> bool:
    if value:
        configure(verbose=STATE.verbose, quiet=True)
    return value


GLOBAL_OPTION_MARK = "_less_global_options"


def with_global_options(command: click.Command) -> click.Command:
    """``command`` (and every command of a group below it) also taking ``-v`` and ``-q`` after its name,
    as they are taken before it: ``less pretrain data.npz -o rep.pt -q`` is ``less -q pretrain ...``;
    and holding its outputs' locks while it runs (``output_option(lock=True)``)."""
    if getattr(command, GLOBAL_OPTION_MARK, False):
        return command
    setattr(command, GLOBAL_OPTION_MARK, True)
    if isinstance(command, click.Group):
        for sub in command.commands.values():
            with_global_options(sub)
    else:
        command.invoke = _locking(command.invoke)
    command.params += [
        click.Option(["-v", "--verbose", "_sub_verbose"], count=True, expose_value=False, hidden=True,
                     callback=_more_verbose, help="More logging on stderr (as before the subcommand)."),
        click.Option(["-q", "--quiet", "_sub_quiet"], is_flag=True, expose_value=False, hidden=True,
                     callback=_quieter, help="Only errors on stderr (as before the subcommand)."),
    ]
    return command


class Group(click.Group):
    """A command group whose listing gives each subcommand's whole first sentence (click cuts it to
    the terminal's width with '...')."""

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, cmd.get_short_help_str(limit=1000)) for name in self.list_commands(ctx)
                if (cmd := self.get_command(ctx, name)) is not None and not cmd.hidden]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


def progress(iterable: Iterable | None = None, **kwargs):
    """Progress on stderr, silent with ``-q``: a tqdm bar on a terminal, else plain lines for a log (one per
    epoch, or per 10 % of the work; no cursor codes: lesscli.cli.progress)."""
    from tqdm import tqdm

    if STATE.quiet or sys.stderr.isatty():
        return tqdm(iterable, file=sys.stderr, disable=STATE.quiet, dynamic_ncols=True, **kwargs)
    from lesscli.cli.progress import PlainProgress

    return PlainProgress(iterable, file=sys.stderr, **kwargs)


def format_option():
    """``--format jsonl|json|table|markdown`` (default: table on a terminal, JSON lines otherwise)."""
    return click.option(
        "--format",
        "fmt",
        type=click.Choice(["jsonl", "json", "table", "markdown"]),
        default=None,
        help="Record format on stdout (default: table on a terminal, else JSON lines).",
    )


def emit_summary(rows: list[dict], output: str | None, fmt: str | None) -> None:
    """A command's summary records: on stdout, or, where stdout carries the output itself (``-o -``), on
    stderr for people (silent with ``-q``)."""
    from lesscli.io.records import emit_records

    if output != "-":
        emit_records(rows, fmt)
    elif not STATE.quiet:
        emit_records(rows, fmt, stream=sys.stderr)


def check_known(names: Iterable[str], known, what: str, option: str) -> None:
    """A usage error (exit 2) for the first of ``names`` not in ``known``, with the nearest known name as a
    hint: "unknown metric 'com_error_3d'; did you mean 'com_error_mm_3d'?"."""
    from lesscli.errors import closest

    for name in names:
        if name not in known:
            hint = closest(name, known)
            raise click.BadParameter(f"unknown {what} '{name}'"
                                     + (f"; did you mean '{hint}'?" if hint else ""),
                                     param_hint=option)


def series_option():
    """``--series NUMBER|UID``: the series of a DICOM folder holding several (``mri-label``, ``info``)."""
    return click.option("--series", default=None, metavar="NUMBER|UID",
                        help="The series to read from a DICOM folder holding several (its SeriesNumber or "
                             "SeriesInstanceUID).")


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

    alias = click.option(old, "_old_" + new.name, hidden=True, expose_value=False, default=None,
                         type=new.type, multiple=new.multiple, callback=take_old,
                         help=f"Old spelling of {spelled}.")
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


class ThreadsType(click.ParamType):
    """``--threads``: a whole number >= 1, or ``auto`` (the load-adaptive choice; lesscli.threads)."""

    name = "threads"

    def convert(self, value, param, ctx):
        from lesscli.threads import parse_threads

        try:
            return parse_threads(value)
        except ValueError:
            self.fail(f"'{value}' is not a whole number >= 1 nor 'auto'", param, ctx)


THROUGHPUT_THREADS = ("CPU threads for torch and BLAS: a number, or 'auto' to follow the machine's load "
                      "(faster beside busy processes, not bit-identical). Default: OMP_NUM_THREADS if set, "
                      "else the usable cores, whatever the load.")
LATENCY_THREADS = ("CPU threads for torch and BLAS (default: two where the load average leaves two cores "
                   "free, else one; at most OMP_NUM_THREADS if set).")


def threads_option(help: str = THROUGHPUT_THREADS):
    """``--threads N|auto``: overrides the thread policy (lesscli.threads) on every command that does torch
    work."""
    return click.option("--threads", type=ThreadsType(), default=None, metavar="N|auto", help=help)


def realtime_option():
    """``--realtime``: latency-bound commands run under the real-time FIFO policy
    (lesscli.realtime.set_realtime)."""
    return click.option("--realtime", is_flag=True,
                        help="Run under the real-time FIFO scheduling policy, so that busy processes do not "
                             "delay updates (Linux; needs root, CAP_SYS_NICE or `ulimit -r`).")


def labelling_options():
    """``--threshold``, ``--min-volume-mm3`` and ``--smooth-mm``: the labelling rule of every command that
    labels images (``image predict``, ``stream``, ``guide``); each defaults to the model's (see
    infer.predict.labelling_rule)."""
    def decorate(func):
        func = click.option("--smooth-mm", "smooth_mm", type=click.FloatRange(min=0), default=None,
                            help="Label from probabilities smoothed across each slice by a Gaussian of this "
                                 "standard deviation (mm; 0: none). Default: the model's, chosen on --val by "
                                 "image fit; else 0.")(func)
        func = click.option("--min-volume-mm3", "min_volume_mm3", type=click.FloatRange(min=0), default=None,
                            help="Drop inclusion regions smaller than this volume (mm^3; 0: keep all). "
                                 "Default: the model's, chosen on --val by image fit; else 0.")(func)
        return click.option("--threshold", type=click.FloatRange(0, 1), default=None,
                            help="Pillar/inclusion exactly where its probability exceeds this (hand-held "
                                 "setting: 0.8; below 0.5 also where it is not the likeliest class). "
                                 "Default: the model's, chosen on --val by image fit; else argmax.")(func)
    return decorate


def device_option(help: str = "auto (CUDA when available, else CPU), cpu, cuda or cuda:N."):
    """``--device``, ``auto`` by default in every command."""
    return click.option("--device", default="auto", show_default=True, help=help)


def checked_output(folder: bool = False, lock: bool = False):
    """A click callback that checks an output path (see lesscli.io.atomic.check_output) at parse time,
    before the command does any work; with ``lock`` it also takes the output's lock for the command's
    run (lesscli.io.atomic.output_lock: a second writer of the same output refuses at its start)."""
    def callback(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
        from lesscli.io.atomic import check_output

        if value is not None:
            check_output(value, folder=folder, option=param.opts[0] if param.opts else "-o")
            if lock:                   # taken when the command starts (a usage error then leaves no lock)
                ctx.meta.setdefault(LOCKS, []).append(value)
        return value
    return callback


LOCKS = "less.output_locks"         # ctx.meta: outputs whose lock the command holds while it runs


def _locking(invoke):
    """``invoke`` holding the locks of the outputs its options named (:func:`checked_output`)."""
    def run(ctx: click.Context):
        import contextlib

        from lesscli.io.atomic import output_lock

        with contextlib.ExitStack() as stack:
            for path in ctx.meta.pop(LOCKS, []):
                stack.enter_context(output_lock(path))
            return invoke(ctx)
    return run


FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


def checked_figure(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """A click callback for a figure path: a .png, .pdf or .svg name (written in that format) or ``-``
    (PNG on stdout), else a usage error; then checked as an output (:func:`checked_output`)."""
    if value is not None and value != "-" and not value.lower().endswith(FIGURE_SUFFIXES):
        raise click.BadParameter(f"'{value}': a figure is written as .png, .pdf or .svg (by its extension)")
    return checked_output()(ctx, param, value)


def output_option(required: bool = True, help: str = "Output file ('-' for stdout).", folder: bool = False,
                  lock: bool = False):
    """``-o/--output PATH``, checked before the command starts (``folder``: the output is a folder;
    ``lock``: held for the run, :func:`checked_output`)."""
    return click.option("-o", "--output", "output", type=click.Path(), required=required, help=help,
                        callback=checked_output(folder, lock))


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


def comma_list(text: str, cast: type, what: str) -> tuple:
    """``'1,2.5'`` -> values of type ``cast``; click.BadParameter naming ``what`` when one does not parse."""
    try:
        return tuple(cast(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"'{text}' is not a comma-separated list of {cast.__name__} values",
                                 param_hint=what) from None


def seed_option(default: int = 0):
    """``--seed``: the random seed of a command that draws (simulation, splits, benchmarks)."""
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
