"""The ``less`` entry point: a click group with lazily loaded subcommands.

Exit codes: 0 ok, 1 runtime/data error (one line on stderr, traceback with ``-v``), 2 usage error,
130 interrupted. A closed stdout pipe (``| head``) ends quietly with 0. Started as a pager (no
subcommand with piped stdin, or a first argument that is an existing file or a pager option) it hands
over to the next ``less`` on PATH so ``git log`` and ``man`` keep working inside the virtual
environment; an unknown first word is a usage error naming the closest subcommand. Started as
``lesscli`` it never pages.
"""

from __future__ import annotations

import importlib
import os
import sys
import traceback

import click

from lesscli import __version__
from lesscli.cli import common
from lesscli.cli.pager import hand_over_to_pager, wants_pager
from lesscli.cli.registry import COMMANDS
from lesscli.errors import LessError, closest

COMPLETE_VAR = "_LESS_COMPLETE"  # shell completion: eval "$(_LESS_COMPLETE=bash_source less)"


class PipeClosed(Exception):
    """stdout's reader went away (``| head``); raised instead of BrokenPipeError, which click would
    turn into exit status 1."""


class LazyGroup(click.Group):
    """A group whose subcommands are imported only when invoked (or their help is asked for)."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except BrokenPipeError:
            raise PipeClosed() from None

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS:
            return None
        module = importlib.import_module(f"lesscli.cli.{COMMANDS[name][0]}")
        return common.with_global_options(module.cli)

    def resolve_command(self, ctx, args):
        name = args[0] if args else ""
        if name and name not in COMMANDS and not name.startswith("-"):
            hint = closest(name, COMMANDS)
            ctx.fail(f"no such command '{name}' (and no such file)." +
                     (f" Did you mean '{hint}'?" if hint else " See 'less --help' for the commands."))
        return super().resolve_command(ctx, args)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, COMMANDS[name][1]) for name in self.list_commands(ctx)]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="More logging on stderr; tracebacks on errors.")
@click.option("-q", "--quiet", is_flag=True, help="Only errors on stderr (no progress bars).")
@click.version_option(__version__, prog_name="less")
def cli(verbose: int, quiet: bool) -> None:
    """less: learned tactile imaging with local scene representations (LESS).

    Every subcommand reads files and writes files; records go to stdout as JSON lines (a table on a
    terminal), progress and logs go to stderr. Use '-' for stdin/stdout. -q and -v may also follow
    the subcommand (less pretrain data.npz -o rep.pt -q).
    """
    common.configure(verbose=verbose, quiet=quiet)


def _fail(message: str, code: int) -> None:
    click.echo(f"less: error: {message}", err=True)
    if common.STATE.verbose:
        traceback.print_exc()
    sys.exit(code)


def main(argv: list[str] | None = None) -> None:
    """Run the CLI on ``argv`` (default ``sys.argv[1:]``) with the exit-code contract."""
    args = list(sys.argv[1:] if argv is None else argv)
    common.STATE.verbose = sum(a in ("-v", "--verbose") or a.startswith("-vv") for a in args)
    try:
        cli.main(args=args, prog_name="less", complete_var=COMPLETE_VAR, standalone_mode=False)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except (KeyboardInterrupt, click.exceptions.Abort):
        _interrupt()
    except (BrokenPipeError, PipeClosed):
        _silence_stdout()
        sys.exit(0)
    except LessError as exc:
        _fail(str(exc), 1)
    except Exception as exc:  # noqa: BLE001 - last line of defence: one line, exit 1
        if _interrupted(exc):
            _interrupt()
        _fail(f"{type(exc).__name__}: {exc} (run with -v for the traceback)", 1)
    _flush_stdout()


def _interrupt() -> None:
    click.echo("less: interrupted", err=True)
    sys.exit(130)


def _interrupted(exc: BaseException) -> bool:
    """Whether a Ctrl-C lies under ``exc``: one that arrives while a module is being imported can come
    back wrapped (Python re-raises it from ``__set_name__`` as a RuntimeError)."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _flush_stdout() -> None:
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        _silence_stdout()


def _silence_stdout() -> None:
    """After EPIPE, point stdout at /dev/null so the interpreter's final flush stays quiet."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def entry() -> None:
    """Console-script entry: pager hand-over first (never for the ``lesscli`` alias, nor for a shell's
    completion request, which comes without a subcommand and often without a terminal), then the CLI."""
    args = sys.argv[1:]
    as_pager = os.path.basename(sys.argv[0]) == "less" and COMPLETE_VAR not in os.environ
    if as_pager and wants_pager(args, set(COMMANDS), stdin_is_tty=sys.stdin.isatty()):
        hand_over_to_pager(args)
        return
    main(args)


if __name__ == "__main__":
    entry()
