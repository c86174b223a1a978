"""Scene files: validation with did-you-mean errors, overrides, pipeline compilation."""

import subprocess
import sys

import pytest

from lesscli.errors import DataError
from lesscli.sim.effects import EFFECTS
from lesscli.sim.pipeline import compile_pipeline
from lesscli.sim.scene import apply_overrides, load_scene, parse_scene, parse_value

BASE = {"phantoms": {"set": "single", "limit": 1, "orientations": [0]}, "contact": {"tier": "winkler"},
        "motion": {"kind": "poke", "n_traj": 3}}


def scene(**sections):
    return parse_scene({**BASE, **sections}, "s.toml")


@pytest.mark.parametrize("doc, message", [
    ({"motoin": {}}, "s.toml: unknown key 'motoin'; did you mean 'motion'?"),
    ({"motion": {"kind": "poke", "n_trajs": 3}},
     "unknown key 'motion.n_trajs'; did you mean 'motion.n_traj'?"),
    ({"motion": {"kind": "pokes"}}, "motion.kind = 'pokes' is not known; did you mean 'poke'?"),
    ({"effects": {"nosie": {}}}, "unknown key 'effects.nosie'; did you mean 'effects.noise'?"),
    ({"effects": {"noise": {"whte_n": 0.1}}}, "did you mean 'effects.noise.white_n'?"),
    ({"effects": {"shear": {"mu": "high"}}}, "'effects.shear.mu' = 'high' has the wrong type"),
    ({"effects": {"shear": {"mu": -1.0}}}, "effects.shear: mu must lie in"),
    ({"effects": {"pose": {"mode": "drone"}}}, "mode must be one of robot, handheld"),
    ({"contact": {"teir": "green"}}, "did you mean 'contact.tier'?"),
    ({"contact": {"on_invalid": "ignore"}}, "contact.on_invalid = 'ignore' is not known"),
    ({"phantoms": {"set": "singel"}}, "phantoms.set = 'singel' is not known; did you mean 'single'?"),
    ({"phantoms": {"set": "single", "names": ["St12C31"]}},
     "no insert 'St12C31' in set 'single'; did you mean 'St12C13'?"),
    ({"phantoms": {"set": "single", "orientations": [8]}}, "orientations in 0..7"),
    ({"sensor": {"layuot": "xela"}}, "did you mean 'sensor.layout'?"),
    ({"labels": {"shape": [26, 128]}}, "labels.shape needs 3"),
    ({"seed": -1}, "seed must be a non-negative integer"),
])
def test_bad_scenes_name_the_problem(doc, message):
    with pytest.raises(DataError) as exc:
        parse_scene({**BASE, **doc}, "s.toml")
    assert message in str(exc.value) and str(exc.value).startswith("s.toml")


def test_defaults_and_resolution():
    s = scene(effects={"noise": {"white_n": 0.02}, "shear": {"enabled": False}})
    assert s.contact["tier"] == "winkler" and s.contact["on_invalid"] == "keep"
    assert s.motion["params"]["n_traj"] == 3 and s.motion["params"]["spacing_mm"] == 6.0
    assert list(s.effects) == ["noise"] and s.effects["noise"]["white_n"] == 0.02
    assert s.effects["noise"]["baseline"] is True
    assert s.sensor["taxels"] == 30 and len(s.phantoms) == 1 and s.orientations == (0,)
    assert (parse_scene({**BASE, "motion": {"kind": "poke", "force_n": 3.0}}).motion["params"]["force_n"]
            == [3.0, 3.0])


def test_custom_taxel_table():
    s = scene(sensor={"taxel_xy_mm": [[-2.0, 0.0], [2.0, 0.0]], "pitch_mm": 4.0})
    assert s.sensor["taxels"] == 2 and s.sensor["pad_size_mm"] == [8.0, 4.0]
    with pytest.raises(DataError, match="list of \\[x, y\\] pairs"):
        scene(sensor={"taxel_xy_mm": [[1.0, 2.0, 3.0]]})


def test_overrides_parse_toml_values():
    assert parse_value("3") == 3 and parse_value("[1, 2]") == [1, 2] and parse_value("true") is True
    assert parse_value("green") == "green" and parse_value('"a b"') == "a b"
    doc = apply_overrides(BASE, ["motion.n_traj=7", "effects.noise.white_n=0.5", "contact.tier=fem"], "x")
    assert (doc["motion"]["n_traj"] == 7 and doc["effects"]["noise"]["white_n"] == 0.5
            and doc["contact"]["tier"] == "fem")
    assert BASE["motion"]["n_traj"] == 3                          # the input is not modified
    with pytest.raises(DataError, match="not of the form"):
        apply_overrides(BASE, ["motion.n_traj"], "x")


def test_load_scene_file_and_errors(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text('name = "t"\n[phantoms]\nset = "single"\nlimit = 2\n[motion]\nkind = "primitive"\n')
    s = load_scene(str(path), ["phantoms.limit=1", "motion.slide_mm=[2.0, 4.0]"])
    assert s.name == "t" and len(s.phantoms) == 1 and s.motion["params"]["slide_mm"] == [2.0, 4.0]
    (tmp_path / "bad.toml").write_text("[motion\n")
    with pytest.raises(DataError, match="bad.toml: not valid TOML"):
        load_scene(str(tmp_path / "bad.toml"))
    with pytest.raises(DataError, match="nope.toml: no such scene file"):
        load_scene(str(tmp_path / "nope.toml"))


def test_phantom_file_relative_to_the_scene(tmp_path):
    (tmp_path / "set.toml").write_text('[[phantom]]\nname = "homog"\n')
    (tmp_path / "scene.toml").write_text('[phantoms]\nset = "set.toml"\n')
    assert load_scene(str(tmp_path / "scene.toml")).phantoms[0].name == "homog"


def test_pipeline_order_and_declarations():
    s = scene(effects={name: {} for name in EFFECTS})
    stages = compile_pipeline(s)
    names = [st.name for st in stages]
    assert names[:4] == ["variability:cast", "core:prepare", "core:motion", "tilt"]
    assert names.index("core:contact") < names.index("variability:texture") < names.index("viscoelastic") \
        < names.index("shear") < names.index("sensor") < names.index("noise") < names.index("pose") \
        < names.index("core:finish")
    assert all(st.writes for st in stages)
    bare = [st.name for st in compile_pipeline(scene())]
    assert bare == ["core:prepare", "core:motion", "core:contact", "core:finish"]


def test_absent_and_disabled_effects_are_never_imported():
    code = ("import sys\nfrom lesscli.sim.scene import parse_scene\nfrom lesscli.sim.pipeline import "
            "compile_pipeline\ns = parse_scene({'phantoms': {'limit': 1}, 'effects': {'noise': {}, 'shear': "
            "{'enabled': False}}})\ncompile_pipeline(s)\n"
            "print(sorted(m.rsplit('.', 1)[1] for m in sys.modules if "
            "m.startswith('lesscli.sim.effects.')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['noise']"
