"""Options behave alike everywhere: -q / -v and the lift's bus options after the subcommand, exit 2 for a bad
option value also when it is checked only once the settings are resolved, help that names every choice
and the paper-scale defaults, group listings that do not cut a subcommand's sentence."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner
from factories import random_scanset

from lesscli.cli.main import cli
from lesscli.io.scans import save_scans

LESS = str(Path(sys.executable).parent / "less")


def _less(*args, cwd, env=None):
    return subprocess.run([LESS, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=600,
                          env={**os.environ, **(env or {})}, check=False)


@pytest.fixture
def scans(tmp_path):
    save_scans(str(tmp_path / "s.npz"), random_scanset())
    return tmp_path


def test_quiet_and_verbose_work_after_the_subcommand(scans):
    before = _less("-q", "pretrain", "s.npz", "-o", "a.pt", "--epochs", "1", "--dim", "8", cwd=scans)
    after = _less("pretrain", "s.npz", "-o", "b.pt", "--epochs", "1", "--dim", "8", "-q", cwd=scans)
    assert before.returncode == after.returncode == 0 and before.stderr == after.stderr == ""
    loud = _less("info", "missing.npz", "-v", cwd=scans)
    assert loud.returncode == 1 and "Traceback" in loud.stderr
    detail = _less("pretrain", "s.npz", "-o", "c.pt", "--epochs", "1", "--dim", "8", "-v", cwd=scans)
    assert detail.returncode == 0 and "threads: " in detail.stderr          # -v's info lines
    nested = _less("image", "predict", "c.pt", "s.npz", "-o", "p.npz", "-q", cwd=scans)
    assert nested.returncode == 1 and nested.stderr.count("\n") == 1        # a group's subcommand too


def test_lift_bus_options_follow_the_subcommand(tmp_path):
    """The port given after the subcommand is the one opened (here a missing one: its name in the error),
    not a usage error naming --format."""
    proc = _less("lift", "status", "--port", tmp_path / "no-such-port", cwd=tmp_path)
    assert proc.returncode == 1 and "no-such-port" in proc.stderr and "Did you mean" not in proc.stderr
    help_text = _less("lift", "home", "--help", cwd=tmp_path).stdout
    assert all(f"--{name} " in help_text for name in ("port", "baud", "config", "ids"))


# (command line, the option the usage error names)
BAD_VALUES = {
    "pretrain --epochs -1": (["pretrain", "s.npz", "-o", "r.pt", "--epochs", "-1"], "'--epochs'"),
    "pretrain --lr -1": (["pretrain", "s.npz", "-o", "r.pt", "--lr", "-1"], "'--lr'"),
    "pretrain --model foo": (["pretrain", "s.npz", "-o", "r.pt", "--model", "foo"], "'--model'"),
    "pretrain --model lesss": (["pretrain", "s.npz", "-o", "r.pt", "--model", "lesss"],
                               "did you mean 'less'"),
    "pretrain --dim 0": (["pretrain", "s.npz", "-o", "r.pt", "--dim", "0"], "'--dim'"),
    "pretrain --set unknown key": (["pretrain", "s.npz", "-o", "r.pt", "--set", "train.epoch=3"],
                                   "did you mean 'epochs'"),
    "pretrain --set bad value": (["pretrain", "s.npz", "-o", "r.pt", "--set", "ssl.k_query=0"], "'--set'"),
    "pretrain --set bare key": (["pretrain", "s.npz", "-o", "r.pt", "--set", "batch_size=0"], "'--set'"),
    "image fit --epochs 0": (["image", "fit", "s.npz", "--rep", "r.pt", "-o", "i.pt", "--epochs", "0"],
                             "'--epochs'"),
    "image fit --decoder foo": (["image", "fit", "s.npz", "--rep", "r.pt", "-o", "i.pt", "--decoder", "foo"],
                                "'--decoder'"),
    "image fit --set unknown key": (["image", "fit", "s.npz", "--rep", "r.pt", "-o", "i.pt", "--set",
                                     "image.widht=8"],
                                    "did you mean 'width'"),
    "image fit --dim 5 (click's own)": (["image", "fit", "s.npz", "--rep", "r.pt", "-o", "i.pt", "--dim",
                                         "5"],
                                        "'--dim'"),
}


@pytest.mark.parametrize("case", sorted(BAD_VALUES))
def test_a_bad_option_value_is_a_usage_error_before_anything_is_read(scans, case):
    args, named = BAD_VALUES[case]
    (scans / "s.npz").unlink()                  # nothing is read: the data need not even exist
    proc = _less(*args, cwd=scans)
    assert proc.returncode == 2, proc.stderr
    assert named in proc.stderr and "Traceback" not in proc.stderr
    assert sorted(os.listdir(scans)) == []


def test_the_same_bad_value_in_a_config_file_is_a_data_error_naming_the_file(scans):
    (scans / "bad.toml").write_text("[train]\nepochs = -1\n")
    proc = _less("pretrain", "s.npz", "-o", "r.pt", "--config", "bad.toml", cwd=scans)
    assert proc.returncode == 1 and proc.stderr.strip() == \
        "less: error: bad.toml: setting train.epochs = -1 is invalid: must be >= 1"
    fixed = _less("pretrain", "s.npz", "-o", "r.pt", "--config", "bad.toml", "--epochs", "1", "--dim", "8",
                  "-q", cwd=scans)
    assert fixed.returncode == 0, fixed.stderr           # an option over the file's value repairs it


def test_pretrain_help_names_every_encoder_and_the_defaults_say_they_are_the_papers():
    from lesscli.models.registry import ENCODERS

    runner = CliRunner()
    pretrain = runner.invoke(cli, ["pretrain", "--help"], terminal_width=200).stdout
    assert all(name in pretrain for name in ENCODERS), "name each registered encoder in --model's help"
    fit = runner.invoke(cli, ["image", "fit", "--help"], terminal_width=200).stdout
    assert ("100, the paper's" in pretrain and "300, the paper's" in fit
            and "--epochs 5 for a first look" in fit)


def _groups(command: click.Command, path: str = ""):
    if isinstance(command, click.Group):
        yield path, command
        ctx = click.Context(command)
        for name in command.list_commands(ctx):
            yield from _groups(command.get_command(ctx, name), f"{path} {name}".strip())


def test_group_listings_give_each_subcommand_its_whole_first_sentence():
    runner = CliRunner()
    groups = list(_groups(cli))
    assert {p for p, _ in groups} >= {"", "image", "bench", "pose", "lift", "plot"}
    for path, _group in groups:
        text = runner.invoke(cli, [*path.split(), "--help"], terminal_width=80).stdout
        listing = text.split("Commands:")[-1] if "Commands:" in text else text.split("Benchmarks:")[-1]
        assert "..." not in listing, (path, listing)


def test_threads_and_jobs_take_auto(scans):
    from factories import TINY_SCENE

    (scans / "tiny.toml").write_text(TINY_SCENE)
    proc = _less("-v", "simulate", "tiny.toml", "-o", "x.npz", "--jobs", "auto", "--format", "jsonl",
                 cwd=scans)
    assert proc.returncode == 0 and json.loads(proc.stdout)["jobs"] >= 1 and "--threads auto" in proc.stderr
    assert _less("simulate", "tiny.toml", "-o", "y.npz", "--jobs", "0", cwd=scans).returncode == 2
