"""Dataclass configs with TOML files and ``key=value`` overrides.

Precedence: dataclass defaults < ``--config file.toml`` < explicit command-line options < ``--set``.
A key is ``section.field`` (``train.lr``) or a bare field name when only one section has it (``lr``).
TOML files use the same sections: ``[model]``, ``[train]``, ``[ssl]``.
"""

from __future__ import annotations

import dataclasses
import tomllib
import types
import typing
from dataclasses import dataclass, field

from lesscli.errors import LessError, did_you_mean
from lesscli.io.toml_files import read_toml


@dataclass
class ModelConfig:
    """Encoder and decoder sizes (lengths in mm)."""

    name: str = "less"                  # "less" (paper), "less-taxel" (taxel-aware) or "global"
    dim: int = 128                      # d_z (paper: 1024)
    spacing_mm: float = 6.0
    grid_extent_mm: float = 60.0        # side of the square covered by particles
    receptive_field_mm: float = 10.0    # beta
    max_steps_per_particle: int = 0     # cap on steps each particle sees (earliest kept); 0 = no cap
    n_freq: int = 16                    # wavelengths per pose coordinate in the positional encoding
    force_norm: str = ""                # force scale: "global" (one pooled std), "feature" (per feature),
                                        # "scale" (no centring); "" = the encoder's own (less: global)
    map_contrast: str = "step"          # less-taxel: contrast to the step's mean ("step") or to a plane
                                        # fitted over the step's pressing taxels ("plane")


@dataclass
class LoopConfig:
    """Generic optimisation settings (used by pretraining and imaging alike)."""

    epochs: int = 100
    batch_size: int = 2
    lr: float = 1e-4
    min_lr_ratio: float = 0.0           # cosine decay ends at lr * min_lr_ratio
    weight_decay: float = 0.0
    grad_clip_norm: float = 0.0         # 0 = no clipping
    seed: int = 0
    device: str = "auto"                # auto | cpu | cuda | cuda:N
    num_workers: int = 0


@dataclass
class SSLConfig:
    """Self-supervised force prediction."""

    k_input: int = 16
    k_query: int = 16


@dataclass
class PretrainConfig:
    model: ModelConfig = field(default_factory=ModelConfig)
    train: LoopConfig = field(default_factory=LoopConfig)
    ssl: SSLConfig = field(default_factory=SSLConfig)


# (section.field, test, requirement) checked by check_pretrain_config
_RULES = [("model.dim", lambda v: v >= 1, ">= 1"), ("model.spacing_mm", lambda v: v > 0, "> 0"),
          ("model.grid_extent_mm", lambda v: v >= 0, ">= 0"), ("model.receptive_field_mm", lambda v: v > 0, "> 0"),
          ("model.max_steps_per_particle", lambda v: v >= 0, ">= 0 (0 = no cap)"),
          ("model.n_freq", lambda v: v >= 1, ">= 1"), ("train.epochs", lambda v: v >= 1, ">= 1"),
          ("train.batch_size", lambda v: v >= 1, ">= 1"), ("train.lr", lambda v: v > 0, "> 0"),
          ("train.min_lr_ratio", lambda v: 0 <= v <= 1, "in [0, 1]"),
          ("train.num_workers", lambda v: v >= 0, ">= 0"), ("ssl.k_input", lambda v: v >= 1, ">= 1"),
          ("ssl.k_query", lambda v: v >= 1, ">= 1"),
          ("model.map_contrast", lambda v: v in ("step", "plane"), "step or plane")]


def check_rules(cfg, rules) -> None:
    """Raise LessError naming the first setting of ``cfg`` that breaks ``rules`` ((key, ok, need) tuples)."""
    for key, ok, need in rules:
        section, name = key.split(".")
        value = getattr(getattr(cfg, section), name)
        if not ok(value):
            raise LessError(f"setting {key} = {value!r} is invalid: must be {need}")


def check_sections(cfg, sections: tuple[str, ...]):
    """Pretraining's rules for the settings of ``sections`` only (a config with just those sections)."""
    check_rules(cfg, [rule for rule in _RULES if rule[0].split(".")[0] in sections])
    return cfg


def check_pretrain_config(cfg: PretrainConfig) -> PretrainConfig:
    """Raise LessError naming the first out-of-range setting."""
    check_rules(cfg, _RULES)
    return cfg


def to_dict(cfg) -> dict:
    """Nested plain dict of a config dataclass."""
    return dataclasses.asdict(cfg)


def from_dict(cls, data: dict, where: str = "config"):
    """Build ``cls`` from a nested dict, checking keys and types (LessError names the bad key)."""
    cfg = cls()
    for section, values in data.items():
        if section not in _sections(cfg):
            raise LessError(f"{where}: unknown section [{section}]{did_you_mean(section, _sections(cfg))}")
        if not isinstance(values, dict):
            raise LessError(f"{where}: [{section}] must be a table of settings")
        for key, value in values.items():
            _assign(cfg, f"{section}.{key}", value, where)
    return cfg


def load_config(cls, path: str | None = None, overrides: typing.Iterable[str] = (), explicit: dict | None = None):
    """Defaults, then a TOML file, then ``explicit`` (``{"section.field": value}``), then ``--set`` pairs."""
    cfg = cls()
    if path:
        cfg = from_dict(cls, read_toml(path, "config file"), where=path)
    for key, value in (explicit or {}).items():
        if value is not None:
            _assign(cfg, key, value, "option")
    for item in overrides:
        if "=" not in item:
            raise LessError(f"--set '{item}': expected key=value (e.g. train.lr=3e-4)")
        key, text = item.split("=", 1)
        _assign(cfg, key.strip(), _parse_text(text.strip()), "--set")
    return cfg


def _sections(cfg) -> dict:
    return {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)}


def _resolve(cfg, key: str, where: str) -> tuple[object, str]:
    sections = _sections(cfg)
    if "." in key:
        section, name = key.split(".", 1)
        if section not in sections:
            raise LessError(f"{where}: unknown section '{section}' in '{key}'{did_you_mean(section, sections)}")
        target = sections[section]
        names = [f.name for f in dataclasses.fields(target)]
        if name not in names:
            raise LessError(f"{where}: unknown setting '{key}'{did_you_mean(name, names)}")
        return target, name
    owners = [s for s, sub in sections.items() if key in {f.name for f in dataclasses.fields(sub)}]
    if len(owners) == 1:
        return sections[owners[0]], key
    every = [f"{s}.{f.name}" for s, sub in sections.items() for f in dataclasses.fields(sub)]
    if owners:
        raise LessError(f"{where}: '{key}' is ambiguous; use one of {', '.join(f'{o}.{key}' for o in owners)}")
    raise LessError(f"{where}: unknown setting '{key}'{did_you_mean(key, [e.split('.', 1)[1] for e in every])}")


def _assign(cfg, key: str, value, where: str) -> None:
    target, name = _resolve(cfg, key, where)
    kind = typing.get_type_hints(type(target))[name]
    setattr(target, name, _coerce(value, kind, f"{where}: '{key}'"))


def _parse_text(text: str):
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text                                            # bare words are strings


def _coerce(value, kind, what: str):
    options = typing.get_args(kind) if isinstance(kind, types.UnionType) else (kind,)
    for option in options:
        if option is type(None) and value is None:
            return None
        if option is bool and isinstance(value, bool):
            return value
        if option is int and isinstance(value, int) and not isinstance(value, bool):
            return value
        if option is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if option is str and isinstance(value, str):
            return value
    names = "/".join(getattr(o, "__name__", str(o)) for o in options)
    raise LessError(f"{what} expects {names}, got {value!r}")
