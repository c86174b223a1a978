"""Registries of model parts by name, with did-you-mean errors, and the builders that turn a part's
settings back into a module. No files here (models never touch them): a checkpoint is opened by
:func:`lesscli.train.representation.load_representation` or :mod:`lesscli.infer.predict`."""

from __future__ import annotations

import torch

from lesscli.errors import LessError, did_you_mean
from lesscli.models.encoders import GlobalEncoder, ParticleEncoder
from lesscli.models.force_decoder import ForceDecoder
from lesscli.models.global_taxel import GlobalTaxelEncoder
from lesscli.models.taxel import TaxelParticleEncoder

# "less" and "global" are the paper's pair; "less-taxel" adds a per-particle taxel stiffness map
# (models/taxel.py) and "global-taxel" is its global partner, one state and one map per scan
ENCODERS: dict[str, type] = {"less": ParticleEncoder, "less-taxel": TaxelParticleEncoder,
                             "global": GlobalEncoder, "global-taxel": GlobalTaxelEncoder}
FORCE_DECODERS: dict[str, type] = {"mlp": ForceDecoder}


def lookup(registry: dict[str, type], name: str, what: str = "model") -> type:
    """``registry[name]``, or a LessError naming the choices and the closest one."""
    if name in registry:
        return registry[name]
    raise LessError(f"unknown {what} '{name}'{did_you_mean(name, registry)} (choices: "
                    f"{', '.join(sorted(registry))})")


def build_decoder(settings: dict, seed: int | None = None) -> torch.nn.Module:
    """An image decoder from its settings (``decoder_settings`` at fit time, ``config['decoder']`` in a
    checkpoint), initialised from ``seed`` (the global RNG is restored)."""
    from lesscli.models.imager import DECODERS

    kwargs = dict(settings)
    cls = lookup(DECODERS, kwargs.pop("name"), "decoder")
    for key in ("shape", "patch_spacing_mm"):
        if key in kwargs:
            kwargs[key] = tuple(kwargs[key])
    with torch.random.fork_rng(devices=[]):
        if seed is not None:
            torch.manual_seed(seed)
        return cls(**kwargs)


def build_encoder(config: dict):
    """Rebuild an encoder from ``encoder.config()`` (a dict with ``name`` and constructor arguments)."""
    kwargs = dict(config)
    cls = lookup(ENCODERS, kwargs.pop("name"), "encoder")
    if "grid_center_mm" in kwargs:
        kwargs["grid_center_mm"] = tuple(kwargs["grid_center_mm"])
    return cls(**kwargs)
