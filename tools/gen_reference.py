"""Write docs/reference/: one page per subcommand, from the CLI's own ``--help``.

    python tools/gen_reference.py            # rewrite the pages (make reference)
    python tools/gen_reference.py --check    # exit 1 naming the pages that differ from today's CLI

A group's page (``image``, ``bench``, ``lift``, ``pose``, ``plot``) holds its own help and then one
section per subcommand. The help is formatted at a fixed width, so the pages do not depend on the
terminal that wrote them. tests/test_docs.py runs ``--check`` in a fresh process (click caches each
command's help option the first time it is asked for) and fails when a page drifts from the code.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

import click

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "docs" / "reference"
WIDTH = 100
HEADER = "<!-- written by tools/gen_reference.py from the CLI's --help; do not edit, run `make reference` -->"


def _help(command: click.Command, path: list[str], parent: click.Context | None) -> tuple[str, click.Context]:
    ctx = click.Context(command, info_name=path[-1], parent=parent, terminal_width=WIDTH,
                        max_content_width=WIDTH)
    return command.get_help(ctx), ctx


def _leaves(command: click.Command, path: list[str], parent: click.Context | None):
    """(path, help) of ``command`` and, for a group, of every subcommand under it, depth first."""
    text, ctx = _help(command, path, parent)
    yield path, text
    if isinstance(command, click.Group):
        for name in command.list_commands(ctx):
            yield from _leaves(command.get_command(ctx, name), [*path, name], ctx)


def pages() -> dict[str, str]:
    """File name under docs/reference/ -> its text, for every subcommand of today's CLI."""
    sys.path.insert(0, str(ROOT))
    from lesscli.cli.main import cli
    from lesscli.cli.registry import COMMANDS

    # the group's context settings (-h as well as --help) reach every subcommand, as when `less` runs
    root = click.Context(cli, info_name="less", terminal_width=WIDTH, max_content_width=WIDTH,
                         **cli.context_settings)
    out = {}
    for name in sorted(COMMANDS):
        command = importlib.import_module(f"lesscli.cli.{COMMANDS[name][0]}").cli
        lines = [HEADER, "", f"# less {name}", "", COMMANDS[name][1], ""]
        for path, text in _leaves(command, ["less", name], root):
            if len(path) > 2:
                lines += [f"## {' '.join(path)}", ""]
            lines += ["```text", text.rstrip(), "```", ""]
        out[f"{name}.md"] = "\n".join(lines)
    index = [HEADER, "", "# Reference", "",
             "One page per subcommand, written from its `--help` (`less CMD --help` prints the same).", "",
             "| command | what it does |", "|---|---|"]
    index += [f"| [`less {n}`]({n}.md) | {COMMANDS[n][1].replace('|', '/')} |" for n in sorted(COMMANDS)]
    index += ["", "The settings that `--config` files and `--set KEY=VALUE` reach, with their defaults:",
              ("[settings](settings.md). Every file format, as the code that reads it defines it: "
               "[formats](formats.md).")]
    top = cli.get_help(root)
    index += ["", "## less", "", "```text", top.rstrip(), "```", ""]
    out["index.md"] = "\n".join(index)
    out["settings.md"] = _settings(cli)
    out["formats.md"] = _formats()
    return out


FORMATS = [  # (title, module whose docstring defines the format)
    ("Scan set (`.npz`, `less.scans/1`)", "lesscli/io/scans.py"),
    ("Sensor layout (a scan set's `meta['sensor']`)", "lesscli/io/sensor.py"),
    ("Label volume (NIfTI, or inside a scan set)", "lesscli/io/labels.py"),
    ("Prediction (`.npz`, `less.pred/1`)", "lesscli/io/predictions.py"),
    ("Checkpoint (`.pt`)", "lesscli/io/checkpoint.py"),
    ("Records (JSON lines)", "lesscli/io/records.py"),
    ("Live samples (`less stream -`)", "lesscli/infer/live.py"),
]


def _formats() -> str:
    """The file formats, each from the module docstring (and ``KEYS`` table) of the code that reads and
    writes it."""
    import ast

    lines = [HEADER, "", "# File formats", "",
             "Each format as the module that reads and writes it defines it (its docstring and table of",
             "keys); `less info FILE` describes any such file.", ""]
    for title, path in FORMATS:
        tree = ast.parse((ROOT / path).read_text())
        lines += [f"## {title}", "", f"From `{path}`:", "", "```text", ast.get_docstring(tree).rstrip()]
        keys = [n.value.value for n in tree.body if isinstance(n, ast.Assign) and len(n.targets) == 1
                and getattr(n.targets[0], "id", None) == "KEYS"]
        lines += ["", keys[0].rstrip()] if keys else []     # the module's table of keys, where it has one
        lines += ["```", ""]
    return "\n".join(lines)


SETTINGS = [  # (title, arguments of a --print-config run, what the settings are)
    ("less simulate", ["simulate", "poke", "-o", "x.npz", "EFFECTS"],
     ("A scene file's tables with their defaults: the packaged `poke` scene with every effect switched on "
      "(an effect runs only where its table is in the scene; `less simulate SCENE --print-config` prints "
      "any scene's).")),
    ("less pretrain", ["pretrain", "data.npz", "-o", "rep.pt"],
     "The `--config` tables of `less pretrain` (`[model]`, `[train]`, `[ssl]`) with their defaults."),
    ("less image fit", ["image", "fit", "data.npz", "--rep", "rep.pt", "-o", "imager.pt"],
     "The `--config` tables of `less image fit` (`[image]`, `[train]`, `[loss]`) with their defaults."),
]


def _settings(cli: click.Group) -> str:
    """The resolved settings of the commands that take ``--config`` / ``--set``, from ``--print-config``."""
    from click.testing import CliRunner

    lines = [HEADER, "", "# Settings", "",
             "Settings come in layers: defaults < a TOML file (the scene, or `--config FILE`) < options <",
             "`--set key=value` (dotted keys, `--set train.lr=3e-4`). These are the defaults, as",
             "`--print-config` prints them.", ""]
    runner = CliRunner(env={"LESS_CACHE_DIR": "~/.cache/less/contact"})
    from lesscli.sim.effects import EFFECTS

    for title, args, what in SETTINGS:
        if "EFFECTS" in args:                                   # every effect on, with its defaults
            args = [a for a in args if a != "EFFECTS"] + [f"--set=effects.{e}={{}}" for e in EFFECTS]
        result = runner.invoke(cli, [*args, "--print-config"], catch_exceptions=False)
        if result.exit_code != 0:
            raise RuntimeError(f"less {' '.join(args)} --print-config exited {result.exit_code}: "
                               f"{result.output}")
        lines += [f"## {title}", "", what, "", "```toml", result.output.rstrip(), "```", ""]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    args = parser.parse_args()
    want = pages()
    have = {p.name: p.read_text() for p in OUT.glob("*.md")} if OUT.is_dir() else {}
    if args.check:
        stale = sorted(n for n in want.keys() | have.keys() if want.get(n) != have.get(n))
        for name in stale:
            print(f"docs/reference/{name}: differs from the CLI's help (run make reference)", file=sys.stderr)
        return 1 if stale else 0
    OUT.mkdir(parents=True, exist_ok=True)
    for name in have.keys() - want.keys():
        (OUT / name).unlink()
    for name, text in want.items():
        (OUT / name).write_text(text)
    print(f"wrote {len(want)} pages to {OUT.relative_to(ROOT)}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
