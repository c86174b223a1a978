"""Scene files (TOML): phantoms, sensor, contact tier, motion and the enabled effects.

Example (every key with its default: docs/reference/settings.md; more in ``lesscli/scenes/``)::

    name = "poke"
    [phantoms]
    set = "single"            # single | multiple | large | random | a .toml/.json phantom file
    [contact]
    tier = "green"            # winkler | green | fem
    [effects.noise]           # one table per enabled effect; absent = off
    white_n = 0.01

``set = "random"`` draws the training family of ``[phantoms.random]``'s ranges (:class:`RandomRanges`;
ignored for other sets). Unknown keys are errors that name the closest valid key. Options (``--seed``),
then ``--set a.b=value`` overrides, apply to the document before validation (lesscli.io.overrides).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from lesscli.errors import DataError, did_you_mean
from lesscli.io.overrides import apply_overrides, parse_value  # noqa: F401 - parse_value re-exported
from lesscli.io.sensor import xela_uscu
from lesscli.io.toml_files import read_toml
from lesscli.phantom.catalogue import CATALOGUES, load_phantom_file
from lesscli.phantom.geometry import DEFAULT_LABEL_SHAPE, Phantom, default_label_spacing
from lesscli.phantom.randomised import RandomRanges, random_set
from lesscli.sim.effects import EFFECTS, load_effect
from lesscli.sim.motion import CONTROLS, MOTION_DEFAULTS

SENSOR_LAYOUTS = {"xela": xela_uscu}
RANDOM_SET = "random"                         # phantoms.set drawing the randomised family
RANDOM_KEYS = set(RandomRanges().to_dict())   # the keys of [phantoms.random]
ON_INVALID = ("keep", "drop", "error")
DEFAULT_TIER = "green"
TOP_KEYS = {"name", "seed", "description", "phantoms", "sensor", "contact", "motion", "labels", "effects"}
SECTION_KEYS = {
    "phantoms": {"set", "names", "limit", "orientations", "random"},
    "sensor": {"layout", "name", "taxel_xy_mm", "pad_size_mm", "pitch_mm", "noise_n", "max_force_n"},
    "contact": {"tier", "cache_dir", "on_invalid", "params"},
    "labels": {"shape", "spacing_mm"},
}


@dataclass
class Scene:
    """A validated scene (see the module docstring)."""

    name: str
    seed: int
    phantoms: list[Phantom]
    orientations: tuple[int, ...]
    sensor: dict
    contact: dict
    motion: dict
    labels: dict
    effects: dict[str, dict] = field(default_factory=dict)
    source: str = "<scene>"
    doc: dict = field(default_factory=dict)


def _fail_key(where: str, key: str, allowed) -> None:
    prefix = key.rsplit(".", 1)[0] + "." if "." in key else ""
    valid = {prefix + name for name in allowed}
    raise DataError(f"{where}: unknown key '{key}'"
                    + did_you_mean(key, valid, f" (valid: {', '.join(sorted(allowed))})"))


def _fail_value(where: str, key: str, value, allowed) -> None:
    raise DataError(f"{where}: {key} = '{value}' is not known{did_you_mean(str(value), allowed)}"
                    f" (valid: {', '.join(sorted(allowed))})")


def check_keys(table: dict, allowed, where: str, prefix: str = "") -> None:
    """Raise DataError for the first key of ``table`` not in ``allowed``, suggesting the closest."""
    if not isinstance(table, dict):
        raise DataError(f"{where}: '{prefix.rstrip('.') or 'scene'}' must be a table")
    for key in table:
        if key not in allowed:
            _fail_key(where, prefix + key, allowed)


def _is_range(ref) -> bool:
    return isinstance(ref, list) and len(ref) == 2 and all(isinstance(v, (int, float)) for v in ref)


def _check_types(values: dict, defaults: dict, where: str, prefix: str) -> dict:
    """Check value types against the defaults; a number given for a [low, high] range becomes [v, v]."""
    out = dict(values)
    for key, value in values.items():
        ref = defaults.get(key)
        if ref is None:
            continue
        if _is_range(ref) and isinstance(value, (int, float)) and not isinstance(value, bool):
            out[key] = value = [value, value]
        if (isinstance(ref, str) != isinstance(value, str) or isinstance(ref, list) != isinstance(value, list)
                or (isinstance(ref, (int, float)) and not isinstance(ref, bool) and
                    (isinstance(value, bool) or not isinstance(value, (int, float, list))))):
            raise DataError(f"{where}: '{prefix}{key}' = {value!r} has the wrong type "
                            f"(default is {ref!r})")
    return out


def _random_ranges(table, where: str, seed: int) -> RandomRanges:
    """The ranges of ``[phantoms.random]``; the family's seed defaults to the scene's."""
    check_keys(table, RANDOM_KEYS, where, "phantoms.random.")
    return RandomRanges.from_dict({"seed": seed, **table}, f"{where}: phantoms.random")


def _phantoms(table: dict, where: str, base_dir: str, seed: int) -> tuple[list[Phantom], tuple[int, ...]]:
    check_keys(table, SECTION_KEYS["phantoms"], where, "phantoms.")
    which = str(table.get("set", "single"))
    if which in CATALOGUES:
        phantoms = CATALOGUES[which]()
    elif which == RANDOM_SET:
        phantoms = random_set(_random_ranges(table.get("random", {}), where, seed))
    elif which.endswith((".toml", ".json")):
        path = which if os.path.isabs(which) or os.path.exists(which) else os.path.join(base_dir, which)
        phantoms = load_phantom_file(path)
    else:
        _fail_value(where, "phantoms.set", which, [*CATALOGUES, RANDOM_SET])
    if "names" in table:
        known = {p.name: p for p in phantoms}
        for name in table["names"]:
            if name not in known:
                raise DataError(f"{where}: phantoms.names: no insert '{name}' in set '{which}'"
                                + did_you_mean(name, known))
        phantoms = [known[n] for n in table["names"]]
    if "limit" in table:
        phantoms = phantoms[: int(table["limit"])]
    orientations = tuple(int(k) for k in table.get("orientations", range(8)))
    if not phantoms or not orientations or any(not 0 <= k < 8 for k in orientations):
        raise DataError(f"{where}: phantoms: need at least one insert and orientations in 0..7")
    return phantoms, orientations


def _sensor(table: dict, where: str) -> dict:
    """The sensor layout, with the sensor's white noise per taxel and force range (N) when the table gives
    them."""
    check_keys(table, SECTION_KEYS["sensor"], where, "sensor.")
    extra = {}
    for key in ("noise_n", "max_force_n"):
        if key in table:
            if isinstance(table[key], bool) or not isinstance(table[key], (int, float)) or not table[key] > 0:
                raise DataError(f"{where}: sensor.{key} must be a number > 0, got {table[key]!r}")
            extra[key] = float(table[key])
    return {**_layout(table, where), **extra}


def _layout(table: dict, where: str) -> dict:
    if "taxel_xy_mm" not in table:
        layout = table.get("layout", "xela")
        if layout not in SENSOR_LAYOUTS:
            _fail_value(where, "sensor.layout", layout, SENSOR_LAYOUTS)
        return SENSOR_LAYOUTS[layout]()
    xy = table["taxel_xy_mm"]
    if not xy or any(not isinstance(r, list) or len(r) != 2 for r in xy):
        raise DataError(f"{where}: sensor.taxel_xy_mm must be a list of [x, y] pairs in mm")
    xs, ys = [r[0] for r in xy], [r[1] for r in xy]
    pitch = float(table.get("pitch_mm", 4.7))
    size = table.get("pad_size_mm", [max(xs) - min(xs) + pitch, max(ys) - min(ys) + pitch])
    return {"name": str(table.get("name", "custom")), "taxels": len(xy), "axes": ["x", "y", "z"],
            "pitch_mm": pitch, "pad_size_mm": [float(v) for v in size],
            "taxel_xy_mm": [[float(a), float(b)] for a, b in xy]}


def _contact(table: dict, where: str) -> dict:
    check_keys(table, SECTION_KEYS["contact"], where, "contact.")
    on_invalid = table.get("on_invalid", "keep")
    if on_invalid not in ON_INVALID:
        _fail_value(where, "contact.on_invalid", on_invalid, ON_INVALID)
    cache = table.get("cache_dir") or os.environ.get("LESS_CACHE_DIR") or \
        os.path.join(os.path.expanduser("~"), ".cache", "less", "contact")
    return {"tier": str(table.get("tier", DEFAULT_TIER)), "params": dict(table.get("params", {})),
            "cache_dir": cache, "on_invalid": on_invalid}


def _motion(table: dict, where: str) -> dict:
    kind = table.get("kind", "poke")
    if kind not in MOTION_DEFAULTS:
        _fail_value(where, "motion.kind", kind, MOTION_DEFAULTS)
    params = {k: v for k, v in table.items() if k != "kind"}
    check_keys(params, MOTION_DEFAULTS[kind], where, "motion.")
    params = _check_types(params, MOTION_DEFAULTS[kind], where, "motion.")
    resolved = {**MOTION_DEFAULTS[kind], **params}
    if resolved.get("control", "force") not in CONTROLS:
        _fail_value(where, "motion.control", resolved['control'], CONTROLS)
    if int(resolved["n_traj"]) < 1:
        raise DataError(f"{where}: motion.n_traj must be at least 1")
    return {"kind": kind, "params": resolved}


def _effects(table: dict, where: str) -> dict[str, dict]:
    check_keys(table, EFFECTS, where, "effects.")
    out = {}
    for name in EFFECTS:                       # registry order, not file order
        if name not in table:
            continue
        params = table[name]
        if not isinstance(params, dict):
            raise DataError(f"{where}: 'effects.{name}' must be a table")
        if params.get("enabled", True) is False:
            continue                           # switched off: never imported
        params = {k: v for k, v in params.items() if k != "enabled"}
        module = load_effect(name)
        check_keys(params, set(module.DEFAULTS) | {"enabled"}, where, f"effects.{name}.")
        params = _check_types(params, module.DEFAULTS, where, f"effects.{name}.")
        resolved = {**module.DEFAULTS, **params}
        if hasattr(module, "validate"):
            module.validate(resolved, f"{where}: effects.{name}")
        out[name] = resolved
    return out


def _labels(table: dict, where: str) -> dict:
    check_keys(table, SECTION_KEYS["labels"], where, "labels.")
    shape = tuple(int(v) for v in table.get("shape", DEFAULT_LABEL_SHAPE))
    spacing = table.get("spacing_mm")
    if len(shape) != 3 or min(shape) < 1 or (spacing is not None
                                             and (len(spacing) != 3 or min(spacing) <= 0)):
        raise DataError(f"{where}: labels.shape needs 3 positive sizes and labels.spacing_mm 3 positive "
                        "values")
    return {"shape": shape, "spacing_mm": None if spacing is None else tuple(float(v) for v in spacing)}


def label_spacing_for(phantom: Phantom, labels: dict) -> tuple[float, float, float]:
    """The scene's label spacing, or the default scaled in-plane with the insert width (large set: 2x)."""
    return (labels["spacing_mm"] if labels["spacing_mm"] is not None
            else default_label_spacing(phantom.width_mm))


def parse_scene(doc: dict, where: str = "<scene>", base_dir: str = ".") -> Scene:
    """Validate a scene document (parsed TOML) into a Scene."""
    check_keys(doc, TOP_KEYS, where)
    for key in ("phantoms", "sensor", "contact", "motion", "labels", "effects"):
        if not isinstance(doc.get(key, {}), dict):
            raise DataError(f"{where}: '{key}' must be a table")
    seed = doc.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise DataError(f"{where}: seed must be a non-negative integer, got {seed!r}")
    phantoms, orientations = _phantoms(doc.get("phantoms", {}), where, base_dir, seed)
    return Scene(name=str(doc.get("name", os.path.splitext(os.path.basename(where))[0])), seed=seed,
                 phantoms=phantoms, orientations=orientations, sensor=_sensor(doc.get("sensor", {}), where),
                 contact=_contact(doc.get("contact", {}), where),
                 motion=_motion(doc.get("motion", {}), where), labels=_labels(doc.get("labels", {}), where),
                 effects=_effects(doc.get("effects", {}), where), source=where, doc=doc)


def load_scene(path: str, overrides: list[str] | tuple[str, ...] = (), options: dict | None = None) -> Scene:
    """Read a scene file, apply ``options`` (dotted key -> value, None = not given) and the ``--set``
    ``overrides`` over it, and validate; errors name the file."""
    doc = apply_overrides(read_toml(path, "scene file"), overrides, path, options)
    return parse_scene(doc, path, os.path.dirname(os.path.abspath(path)))


def scene_document(scene: Scene) -> dict:
    """``scene`` as a TOML-ready document with every default filled in (``less simulate --print-config``);
    read back as a scene file it gives the same scene. A selection of inserts (``names``, ``limit``) is
    written as the names it selects."""
    table = scene.doc.get("phantoms", {})
    phantoms = {"set": str(table.get("set", "single")), "orientations": list(scene.orientations)}
    if "names" in table or "limit" in table:
        phantoms["names"] = [p.name for p in scene.phantoms]
    if phantoms["set"] == RANDOM_SET:
        phantoms["random"] = _random_ranges(table.get("random", {}), scene.source, scene.seed).to_dict()
    labels = {"shape": list(scene.labels["shape"]), "spacing_mm": scene.labels["spacing_mm"]}
    # a set: sorted, so reruns agree
    sensor = {k: scene.sensor[k] for k in sorted(SECTION_KEYS["sensor"]) if k in scene.sensor}
    motion = {"kind": scene.motion["kind"], **scene.motion["params"]}
    return {"name": scene.name, "seed": scene.seed, "description": scene.doc.get("description"),
            "phantoms": phantoms, "sensor": sensor, "contact": dict(scene.contact), "motion": motion,
            "labels": labels, "effects": dict(scene.effects)}
