"""Dataclass configs of the training commands, layered by lesscli.io.overrides.

Precedence: dataclass defaults < ``--config file.toml`` < explicit command-line options < ``--set``.
A key is ``section.field`` (``train.lr``) or a bare field name when only one section has it (``lr``).
TOML files use the same sections: ``[model]``, ``[train]``, ``[ssl]``.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field

from lesscli.errors import LessError
from lesscli.io.overrides import resolve_dataclass
from lesscli.io.toml_files import read_toml


@dataclass
class ModelConfig:
    """Encoder and decoder sizes (lengths in mm)."""

    name: str = "less"                  # "less", "global" (the paper's pair), "less-taxel", "global-taxel"
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
    map_cells: int = 7                  # less-taxel: cells per side of each particle's stiffness map
    map_pitch_mm: float = 2.5           # less-taxel: distance between map cells


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
          ("model.grid_extent_mm", lambda v: v >= 0, ">= 0"),
          ("model.receptive_field_mm", lambda v: v > 0, "> 0"),
          ("model.max_steps_per_particle", lambda v: v >= 0, ">= 0 (0 = no cap)"),
          ("model.n_freq", lambda v: v >= 1, ">= 1"), ("train.epochs", lambda v: v >= 1, ">= 1"),
          ("train.batch_size", lambda v: v >= 1, ">= 1"), ("train.lr", lambda v: v > 0, "> 0"),
          ("train.min_lr_ratio", lambda v: 0 <= v <= 1, "in [0, 1]"),
          ("train.num_workers", lambda v: v >= 0, ">= 0"), ("ssl.k_input", lambda v: v >= 1, ">= 1"),
          ("ssl.k_query", lambda v: v >= 1, ">= 1"),
          ("model.map_contrast", lambda v: v in ("step", "plane"), "step or plane"),
          ("model.map_cells", lambda v: v >= 1, ">= 1"), ("model.map_pitch_mm", lambda v: v > 0, "> 0")]


class SettingError(LessError):
    """A setting out of range or unknown: ``key`` (``section.field``) holds ``value``, which must be ``need``.

    The command line tells where the value came from (an option or ``--set``: a usage error; a
    ``--config`` file: a data error naming the file)."""

    def __init__(self, key: str, value, need: str) -> None:
        super().__init__(f"setting {key} = {value!r} is invalid: must be {need}")
        self.key, self.value, self.need = key, value, need


def check_rules(cfg, rules) -> None:
    """Raise SettingError naming the first setting of ``cfg`` that breaks ``rules`` ((key, ok, need)
    tuples)."""
    for key, ok, need in rules:
        section, name = key.split(".")
        value = getattr(getattr(cfg, section), name)
        if not ok(value):
            raise SettingError(key, value, need)


def check_sections(cfg, sections: tuple[str, ...]):
    """Pretraining's rules for the settings of ``sections`` only (a config with just those sections)."""
    check_rules(cfg, [rule for rule in _RULES if rule[0].split(".")[0] in sections])
    return cfg


def check_pretrain_config(cfg: PretrainConfig) -> PretrainConfig:
    """Raise SettingError naming the first out-of-range setting or an unknown encoder."""
    from lesscli.errors import closest
    from lesscli.models.registry import ENCODERS

    check_rules(cfg, _RULES)
    if cfg.model.name not in ENCODERS:
        hint = closest(cfg.model.name, ENCODERS)
        raise SettingError("model.name", cfg.model.name, f"one of {', '.join(sorted(ENCODERS))}"
                           + (f" (did you mean '{hint}'?)" if hint else ""))
    return cfg


def to_dict(cfg) -> dict:
    """Nested plain dict of a config dataclass."""
    return dataclasses.asdict(cfg)


def load_config(cls, path: str | None = None, overrides: typing.Iterable[str] = (),
                explicit: dict | None = None):
    """Defaults, then a TOML file, then ``explicit`` (``{"section.field": value}``, None = not given), then
    ``--set`` pairs (lesscli.io.overrides: a key is ``section.field`` or a field that one section has)."""
    doc = read_toml(path, "config file") if path else None
    return resolve_dataclass(cls, doc, path or "config", explicit, overrides, short_keys=True)
