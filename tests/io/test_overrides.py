"""The one ``key=value`` / layered-settings module (lesscli.io.overrides), the TOML writer, and
``--print-config`` on every command that takes ``--set``."""

import math
import tomllib
from dataclasses import dataclass, field

import pytest
from click.testing import CliRunner

from lesscli.cli.main import cli
from lesscli.errors import DataError
from lesscli.io.overrides import apply_overrides, parse_assignment, parse_value, resolve_dataclass
from lesscli.io.toml_files import dump_toml
from lesscli.sim.scene import parse_scene, scene_document

# ------------------------------------------------------------------------------------------ values


@pytest.mark.parametrize("text,expected", [
    ("3", 3), ("-2", -2), ("1e-4", 1e-4), ("0.5", 0.5), ("true", True), ("false", False),
    ("[1, 2]", [1, 2]), ("[[1, 2], [3, 4]]", [[1, 2], [3, 4]]), ('"a b"', "a b"), ("'x'", "x"),
    ("{ low = 1, high = 2 }", {"low": 1, "high": 2}), (" 7 ", 7),
    ("green", "green"), ("cuda:0", "cuda:0"), ("scenes/a.toml", "scenes/a.toml"), ("1e-4x", "1e-4x"),
    ("2024-01-01", "2024-01-01"),          # TOML would read a date: settings take the text
])
def test_values_parse_as_toml_else_as_text(text, expected):
    value = parse_value(text)
    assert value == expected and type(value) is type(expected)


def test_inf_is_a_float():
    assert math.isinf(parse_value("inf"))


@pytest.mark.parametrize("text,match", [("[1,", "malformed value '\\[1,'"), ('"open', "malformed value"),
                                        ("{ a = ", "malformed value"), ("", "empty value"),
                                        ("1\nb = 2", "line break")])
def test_malformed_values_are_one_line_errors(text, match):
    with pytest.raises(DataError, match=match) as info:
        parse_value(text, "--set 'k'")
    assert "\n" not in str(info.value) and str(info.value).startswith("--set 'k': ")


@pytest.mark.parametrize("item,keys,value", [("a=1", ("a",), 1), ("train.lr = 3e-4", ("train", "lr"), 3e-4),
                                             ("effects.noise.white_n=0.5", ("effects", "noise", "white_n"),
                                              0.5),
                                             ("names=[\"a=b\"]", ("names",), ["a=b"])])
def test_assignments_split_at_the_first_equals_and_the_dots(item, keys, value):
    assert parse_assignment(item) == (keys, value)


@pytest.mark.parametrize("item", ["lr", "=3", "a..b=1", "a.=1"])
def test_a_pair_that_is_not_key_value_is_an_error(item):
    with pytest.raises(DataError, match=f"--set '{item}' is not of the form key=value"):
        parse_assignment(item)


# -------------------------------------------------------------------------- documents (no schema)


def test_document_overrides_nest_layer_and_copy():
    doc = {"seed": 0, "motion": {"n_traj": 3}}
    out = apply_overrides(doc, ["effects.noise.white_n=0.5", "seed=2", "motion.kind=poke"], "s.toml",
                          options={"seed": 1, "name": None, "motion.n_traj": 4})
    assert out == {"seed": 2, "motion": {"n_traj": 4, "kind": "poke"}, "effects": {"noise": {"white_n": 0.5}}}
    assert doc == {"seed": 0, "motion": {"n_traj": 3}}
    assert apply_overrides(doc, [], options={"seed": 1})["seed"] == 1      # options over the file
    with pytest.raises(DataError, match="s.toml: --set 'motion.n_traj.x=1': 'motion.n_traj' is a value"):
        apply_overrides(doc, ["motion.n_traj.x=1"], "s.toml")


# ------------------------------------------------------------------------------ dataclass schemas


@dataclass
class _Inner:
    n: int = 1
    x: float = 0.5
    name: str = "a"
    flag: bool = False
    maybe: float | None = None


@dataclass
class _Other:
    n: int = 2
    k: int = 3
    sizes: list = field(default_factory=lambda: [1, 2])


@dataclass
class _Config:
    inner: _Inner = field(default_factory=_Inner)
    other: _Other = field(default_factory=_Other)


@pytest.mark.parametrize("doc,options,sets,expected", [
    (None, None, [], {"n": 1, "x": 0.5, "k": 3}),                                       # defaults
    ({"inner": {"n": 5, "x": 1}}, None, [], {"n": 5, "x": 1.0, "k": 3}),                # file (int -> float)
    ({"inner": {"n": 5}}, {"inner.n": 6, "inner.x": None}, [], {"n": 6, "x": 0.5, "k": 3}),  # options > file
    ({"inner": {"n": 5}}, {"inner.n": 6}, ["inner.n=7", "k=9"], {"n": 7, "x": 0.5, "k": 9}),  # --set wins
    (None, None, ["inner.n=7", "inner.n=8"], {"n": 8, "x": 0.5, "k": 3}),                # last --set wins
])
def test_layers_apply_in_order(doc, options, sets, expected):
    cfg = resolve_dataclass(_Config, doc, "c.toml", options, sets, short_keys=True)
    assert (cfg.inner.n, cfg.inner.x, cfg.other.k) == (expected["n"], expected["x"], expected["k"])
    assert type(cfg.inner.x) is float and isinstance(cfg.inner, _Inner)


def test_typed_values_from_set():
    cfg = resolve_dataclass(_Config, overrides=["inner.name=b c", "inner.flag=true", "inner.maybe=0.8",
                                                "other.sizes=[3, 4, 5]", 'inner.name="quoted"'])
    got = (cfg.inner.name, cfg.inner.flag, cfg.inner.maybe, cfg.other.sizes)
    assert got == ("quoted", True, 0.8, [3, 4, 5])


@pytest.mark.parametrize("sets,match", [
    (["inner.nn=1"], r"--set 'inner.nn=1': \[inner\] unknown key 'nn'; did you mean 'n'\?"),
    (["innr.n=1"], r"--set 'innr.n=1': unknown table 'innr'; did you mean 'inner'\?"),
    (["nn=1"], r"unknown key 'nn'; did you mean 'n'\?"),
    (["n=1"], r"'n' is ambiguous; use one of inner.n, other.n"),
    (["inner.x=fast"], r"'inner.x' must be a number \(expects float\), got 'fast'"),
    (["inner.n=1.5"], r"'inner.n' expects int, got 1.5"),
    (["inner.flag=1"], r"'inner.flag' expects bool, got 1"),
    (["inner.x=true"], r"'inner.x' expects float, got True"),
    (["inner=3"], r"\[inner\] is a table"),
    (["inner.n.z=1"], r"'inner.n' is a setting, not a table"),
    (["inner.x=[1,"], r"malformed value"),
    (["inner.x"], r"not of the form key=value"),
])
def test_bad_overrides_name_the_key(sets, match):
    with pytest.raises(DataError, match=match) as info:
        resolve_dataclass(_Config, overrides=sets, short_keys=True)
    assert "\n" not in str(info.value)


def test_short_keys_only_when_asked():
    with pytest.raises(DataError, match="unknown table 'k'"):
        resolve_dataclass(_Config, overrides=["k=1"])


@pytest.mark.parametrize("doc,match", [
    ({"inner": {"nn": 1}}, r"c.toml: \[inner\] unknown key 'nn'; did you mean 'n'\?"),
    ({"iner": {}}, r"c.toml: unknown table 'iner'; did you mean 'inner'\?"),
    ({"inner": 3}, r"c.toml: \[inner\] must be a table"),
    ({"inner": {"n": {"a": 1}}}, r"c.toml: \[inner\] 'n' is a setting, not a table"),
    ({"inner": {"n": "one"}}, r"c.toml: 'inner.n' must be a number"),
])
def test_bad_files_name_the_file_and_key(doc, match):
    with pytest.raises(DataError, match=match):
        resolve_dataclass(_Config, doc, "c.toml")


# ------------------------------------------------------------------------------------ TOML writer


def test_toml_writer_round_trips():
    doc = {"name": 'say "hi"\n\tdone é\x7f', "seed": 3, "big": 10**15, "rate": 1e-7, "edge": -math.inf,
           "flags": [True, False], "grid": [[1.5, -2.0], [0.0, 3.25]], "unset": None, "weird key": 1,
           "a": {"b": {"c": [1, 2], "empty": {}}, "x": 0.1}, "inline": [{"k": 1}], "end": {}}
    text = dump_toml(doc)
    back = tomllib.loads(text)
    expected = {k: v for k, v in doc.items() if v is not None}
    assert back == expected
    assert "unset" not in text


# -------------------------------------------------------------------------- resolved scene documents


def test_scene_document_reads_back_as_the_same_scene():
    doc = {"name": "t", "seed": 4, "phantoms": {"set": "single", "limit": 2, "orientations": [0, 3]},
           "contact": {"tier": "winkler", "cache_dir": "/tmp/c"},
           "motion": {"kind": "primitive", "n_traj": 3, "slide_mm": [2.0, 4.0]},
           "labels": {"shape": [8, 16, 16]},
           "effects": {"noise": {"white_n": 0.02}, "tilt": {"enabled": False}}}
    scene = parse_scene(doc, "t.toml")
    resolved = tomllib.loads(dump_toml(scene_document(scene)))
    again = parse_scene(resolved, "t.toml")
    for name in ("name", "seed", "phantoms", "orientations", "sensor", "contact", "motion", "labels",
                 "effects"):
        assert getattr(again, name) == getattr(scene, name), name
    assert resolved["motion"]["slide_mm"] == [2.0, 4.0] and resolved["motion"]["kind"] == "primitive"
    assert set(resolved["effects"]) == {"noise"} and len(resolved["phantoms"]["names"]) == 2


def test_random_scene_document_names_the_family():
    doc = {"seed": 2, "phantoms": {"set": "random", "random": {"count": 3}, "orientations": [0]},
           "motion": {"n_traj": 2}}
    resolved = tomllib.loads(dump_toml(scene_document(parse_scene(doc, "r.toml"))))
    assert resolved["phantoms"]["random"]["seed"] == 2 and resolved["phantoms"]["random"]["count"] == 3
    assert [p.name for p in parse_scene(resolved, "r.toml").phantoms] == ["R0s2", "R1s2", "R2s2"]


# -------------------------------------------------------------------------------- --print-config


def _invoke(tmp_path, monkeypatch, args):
    monkeypatch.chdir(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == before        # nothing written
    return tomllib.loads(result.stdout)


def test_simulate_print_config(tmp_path, monkeypatch):
    (tmp_path / "s.toml").write_text('seed = 1\n[phantoms]\nset = "single"\nlimit = 1\n[motion]\nn_traj = 2\n'
                                     '[effects.noise]\n')
    printed = _invoke(tmp_path, monkeypatch, ["simulate", "s.toml", "-o", "out.npz", "--seed", "5",
                                              "--set", "motion.n_traj=7",
                                              "--set", "effects.noise.white_n=0.5", "--print-config"])
    assert printed["motion"]["n_traj"] == 7 and printed["motion"]["kind"] == "poke"
    assert printed["seed"] == 5 and printed["effects"]["noise"]["white_n"] == 0.5
    assert printed["contact"]["tier"] == "green"                       # a default, filled in


def test_simulate_set_wins_over_seed_option(tmp_path, monkeypatch):
    (tmp_path / "s.toml").write_text('[phantoms]\nset = "single"\nlimit = 1\n')
    printed = _invoke(tmp_path, monkeypatch, ["simulate", "s.toml", "-o", "out.npz", "--seed", "5",
                                              "--set", "seed=6", "--print-config"])
    assert printed["seed"] == 6


def test_pretrain_print_config_layers_file_options_and_set(tmp_path, monkeypatch):
    (tmp_path / "c.toml").write_text("[train]\nepochs = 7\nbatch_size = 4\n[model]\ndim = 16\n")
    printed = _invoke(tmp_path, monkeypatch, ["pretrain", "missing.npz", "-o", "rep.pt", "--config", "c.toml",
                                              "--epochs", "3", "--dim", "8", "--set", "dim=12",
                                              "--set", "train.lr=3e-4", "--print-config"])
    train = printed["train"]
    assert (train["epochs"], train["batch_size"], train["lr"]) == (3, 4, 3e-4)
    assert printed["model"]["dim"] == 12 and printed["ssl"]["k_query"] == 16


def test_image_fit_print_config(tmp_path, monkeypatch):
    printed = _invoke(tmp_path, monkeypatch, ["image", "fit", "missing.npz", "--rep", "rep.pt", "-o", "im.pt",
                                              "--dim", "2", "--set", "loss.gamma=1",
                                              "--set", "image.width=64", "--print-config"])
    assert printed["loss"]["gamma"] == 1.0 and (printed["image"]["width"], printed["image"]["dim"]) == (64, 2)
    assert printed["train"]["epochs"] == 300 and "threshold" not in printed["image"]   # None: left out


def test_print_config_does_not_apply_to_the_force_map(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(cli, ["image", "fit", "x.npz", "--model", "forcemap", "-o", "f.pt",
                                      "--print-config"])
    assert result.exit_code == 2 and "--print-config" in result.output


def test_print_config_reports_a_bad_set_like_the_command(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(cli, ["pretrain", "x.npz", "-o", "rep.pt", "--set", "model.dimm=3",
                                      "--print-config"])
    assert result.exit_code == 2 and "did you mean 'dim'" in result.stderr and not result.stdout     # usage


def _commands(group, ctx, path=()):
    import click

    for name in group.list_commands(ctx):
        command = group.get_command(ctx, name)
        if isinstance(command, click.Group):
            yield from _commands(command, ctx, (*path, name))
        else:
            yield " ".join((*path, name)), command


def test_every_command_taking_set_overrides_prints_its_config():
    import click

    ctx = click.Context(cli)
    takes_set = {name for name, command in _commands(cli, ctx)
                 if any("--set" in p.opts and p.metavar == "KEY=VALUE" for p in command.params)}
    printing = {name for name, command in _commands(cli, ctx)
                if any("--print-config" in p.opts for p in command.params)}
    assert takes_set == printing and {"simulate", "pretrain", "image fit"} <= takes_set
