"""One vocabulary across commands: renamed options under both spellings, help text on every option, path
arguments that complete files, --device auto, one orientation syntax, shell completion through the
console script."""

import json
import os
import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from lesscli.cli.common import orientation_list, renamed_option
from lesscli.cli.main import cli

LESS = str(Path(sys.executable).parent / "less")
NOT_PATHS = {("fetch", "records"), ("lift rotate", "orientation")}  # arguments that are not files
PHANTOM = ["phantom", "--set", "single", "--names", "St12C13", "--orientations", "0", "--format", "jsonl"]
MRI_LABEL = ["mri-label", "missing.nii.gz", "-o", "labels.nii.gz"]

# (command line without the option, old spelling, new spelling, value, check of (exit code, stdout, stderr))
RENAMED = {
    "phantom --grid-shape": (PHANTOM + ["--spacing-mm", "2,2,2", "-o", "out"], "--shape", "--grid-shape",
                             "8,32,32", lambda code, out,
                             err: code == 0 and json.loads(out)["shape"] == [8, 32, 32]),
    "phantom --spacing-mm": (PHANTOM + ["--grid-shape", "8,32,32", "-o", "out"], "--spacing", "--spacing-mm",
                             "2,2,2", lambda code, out,
                             err: code == 0 and json.loads(out)["spacing_mm"] == [2, 2, 2]),
    "mri-label --plot": (MRI_LABEL, "--qc", "--plot", "qc.txt",
                         lambda code, out, err: code == 2 and "'qc.txt': expected a .png file" in err),
}

# every old spelling in the command tree: (command, old) -> (required arguments, a value to give)
ALIASES = {
    ("phantom", "--shape"): (["-o", "out"], "8,32,32"),
    ("phantom", "--spacing"): (["-o", "out"], "2,2,2"),
    ("mri-label", "--qc"): (["-o", "labels.nii.gz"], "qc.png"),
    ("bench guide", "--work"): ([], "cache"),
    ("bench imaging", "--repeat"): ([], "3"),
    ("bench imaging", "--batch"): ([], "5"),
    ("bench metrics", "--repeat"): ([], "3"),
    ("stream", "--monitor"): (["m.pt", "s.npz"], "frames"),
}


def walk(command: click.Command, path: str = ""):
    """(path, command) for ``command`` and every subcommand below it."""
    yield path, command
    if isinstance(command, click.Group):
        ctx = click.Context(command)
        for name in command.list_commands(ctx):
            yield from walk(command.get_command(ctx, name), f"{path} {name}".strip())


def invoke(args: list[str], cwd: Path):
    os.chdir(cwd)
    result = CliRunner().invoke(cli, args)
    return result.exit_code, result.stdout, result.stderr


def deprecations(err: str) -> list[str]:
    return [line for line in err.splitlines() if "deprecated" in line]


@pytest.mark.parametrize("case", sorted(RENAMED))
def test_renamed_option_works_under_both_spellings(case, tmp_path, monkeypatch):
    args, old, new, value, check = RENAMED[case]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "new").mkdir()
    (tmp_path / "old").mkdir()
    code, out, err = invoke(args + [new, value], tmp_path / "new")
    assert check(code, out, err) and deprecations(err) == [], err
    code_old, out_old, err_old = invoke(args + [old, value], tmp_path / "old")
    assert check(code_old, out_old, err_old), err_old
    assert out_old == out and (code_old, err_old.replace(deprecations(err_old)[0] + "\n", "")) == (code, err)
    (line,) = deprecations(err_old)
    assert old in line and new in line


def test_every_old_spelling_parses_to_its_new_option(tmp_path, monkeypatch):
    """Parsing only (no command runs): the old spelling fills the new option, the new one wins over it."""
    monkeypatch.chdir(tmp_path)
    found = {}
    for path, command in walk(cli):
        for param in command.params:
            if isinstance(param, click.Option) and param.hidden and (param.help or "").startswith("Old "
                                                                                                  "spelling"):
                (target,) = [p for p in command.params if p.name == param.name.removeprefix("_old_")]
                found[(path, param.opts[0])] = (command, target)
    assert set(found) == set(ALIASES)
    for (path, old), (command, target) in found.items():
        required, value = ALIASES[path, old]
        new = target.opts[-1]
        expected = target.type_cast_value(click.Context(command), value)
        for args in ([old, value], [new, value], [old, "1", new, value], [new, value, old, "1"]):
            ctx = command.make_context(path, required + args)
            assert ctx.params[target.name] == expected, (path, args)


def test_mri_label_old_orientation_count_means_all_eight(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = invoke(MRI_LABEL + ["--orientations", "0-7"], tmp_path)
    assert (code == 2 and "--orientations 0,1,2,3,4,5,6,7 needs --grid phantom" in err
            and not deprecations(err))
    code_old, _, err_old = invoke(MRI_LABEL + ["--orientations", "8"], tmp_path)
    assert code_old == 2 and "--orientations 0,1,2,3,4,5,6,7 needs --grid phantom" in err_old
    assert len(deprecations(err_old)) == 1


def test_renamed_option_new_spelling_wins_and_callback_sees_the_value():
    @click.command()
    @renamed_option("--width", "--width-mm", "width", default="1", callback=lambda ctx, p, v: f"<{v}>",
                    help="A width.")
    def toy(width):
        click.echo(width)

    runner = CliRunner()
    assert runner.invoke(toy, []).stdout == "<1>\n"
    assert runner.invoke(toy, ["--width", "2"]).stdout == "<2>\n"
    assert runner.invoke(toy, ["--width-mm", "3", "--width", "2"]).stdout == "<3>\n"
    assert runner.invoke(toy, ["--width", "2", "--width-mm", "3"]).stdout == "<3>\n"
    help_text = runner.invoke(toy, ["--help"]).stdout
    assert "--width-mm" in help_text and "--width " not in help_text


def test_old_spellings_stay_out_of_help():
    runner = CliRunner()
    for path, old in ALIASES:
        help_text = runner.invoke(cli, [*path.split(), "--help"]).stdout
        assert "Usage:" in help_text and f"{old} " not in help_text, (path, old)


def test_every_option_of_every_command_has_help_text():
    missing = [(path, param.opts) for path, command in walk(cli)
               for param in command.get_params(click.Context(command))
               if isinstance(param, click.Option) and not (param.help or "").strip()]
    assert missing == []


def test_path_arguments_complete_files():
    plain = [(path, param.name) for path, command in walk(cli) for param in command.params
             if isinstance(param, click.Argument) and not isinstance(param.type, click.Path)
             and (path, param.name) not in NOT_PATHS]
    assert plain == []


def test_file_options_complete_files():
    """Outputs, figures and the usual inputs: every option spelled so is a click.Path."""
    names = {"--output", "--plot", "--knob-plot", "--rep", "--config", "--camera", "--calibration", "--nifti",
             "--truth-out", "--scene", "--trajectory", "--tag-to-sensor", "--work-dir", "--cache-dir",
             "--baseline-from", "--pred"}
    checked, plain = 0, []
    for path, command in walk(cli):
        for param in command.params:
            if isinstance(param, click.Option) and not param.is_flag and set(param.opts) & names:
                checked += 1
                if not isinstance(param.type, click.Path):
                    plain.append((path, param.opts))
    assert checked > 40 and plain == []


def test_device_defaults_to_auto_everywhere():
    seen = {path: param.default for path, command in walk(cli) for param in command.params
            if "--device" in getattr(param, "opts", [])}
    assert len(seen) >= 8
    # training commands leave it unset so a config file may choose; their help names the default
    assert {path: d for path, d in seen.items() if d != "auto" and d is not None} == {}


@pytest.mark.parametrize("text, expected", [
    ("0-7", list(range(8))), ("0,2,4", [0, 2, 4]), ("3", [3]), ("0-2,6", [0, 1, 2, 6]), ("6,1", [6, 1]),
])
def test_orientation_list(text, expected):
    assert orientation_list(text) == expected


@pytest.mark.parametrize("text", ["8", "0-8", "a", "", "1,,2", "-1", "0,3-1"])
def test_orientation_list_refuses(text):
    with pytest.raises(click.BadParameter, match=r"0\.\.7|0-7"):
        orientation_list(text)


def _complete(env: dict) -> str:
    proc = subprocess.run([LESS], env={**os.environ, **env}, stdin=subprocess.DEVNULL, capture_output=True,
                          timeout=60, check=True)
    return proc.stdout.decode()


def test_shell_completion_through_the_console_script(tmp_path):
    script = _complete({"_LESS_COMPLETE": "bash_source"})
    assert ("_LESS_COMPLETE=bash_complete" in script
            and "complete -o nosort -F _less_completion less" in script)
    words = _complete({"_LESS_COMPLETE": "bash_complete", "COMP_WORDS": "less phan", "COMP_CWORD": "1"})
    assert words.split() == ["plain,phantom"]
    files = _complete({"_LESS_COMPLETE": "bash_complete", "COMP_WORDS": "less image predict x",
                       "COMP_CWORD": "3"})
    assert files.split() == ["file,x"]
    option = _complete({"_LESS_COMPLETE": "bash_complete", "COMP_WORDS": "less render p.npz -o fig",
                        "COMP_CWORD": "4"})
    assert option.split() == ["file,fig"]
