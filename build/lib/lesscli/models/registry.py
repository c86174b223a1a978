"""Registries of model parts by name, with did-you-mean errors."""

from __future__ import annotations

import torch

from lesscli.errors import DataError, LessError, did_you_mean
from lesscli.io.checkpoint import encoder_state, load_checkpoint
from lesscli.models.encoders import GlobalEncoder, ParticleEncoder
from lesscli.models.force_decoder import ForceDecoder
from lesscli.models.taxel import TaxelParticleEncoder

# "less" is the paper's encoder; "less-taxel" adds a per-particle taxel stiffness map (models/taxel.py)
ENCODERS: dict[str, type] = {"less": ParticleEncoder, "less-taxel": TaxelParticleEncoder, "global": GlobalEncoder}
FORCE_DECODERS: dict[str, type] = {"mlp": ForceDecoder}


def lookup(registry: dict[str, type], name: str, what: str = "model") -> type:
    """``registry[name]``, or a LessError naming the choices and the closest one."""
    if name in registry:
        return registry[name]
    raise LessError(f"unknown {what} '{name}'{did_you_mean(name, registry)} (choices: {', '.join(sorted(registry))})")


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


def load_representation(path: str, map_location: str | torch.device = "cpu"):
    """Rebuild the encoder stored in a checkpoint.

    Returns:
        (encoder, checkpoint): the encoder in eval mode with its weights loaded, and the checkpoint
        dict (``checkpoint["norm_stats"]`` normalises new data exactly as in training).
    """
    ckpt = load_checkpoint(path, map_location)
    enc_cfg = ckpt.get("config", {}).get("encoder")
    if not isinstance(enc_cfg, dict) or "name" not in enc_cfg:
        raise DataError(f"{path}: checkpoint config has no 'encoder' section; not a representation")
    encoder = build_encoder(enc_cfg)
    state = encoder_state(ckpt["model_state"])
    try:
        encoder.load_state_dict(state)
    except RuntimeError as exc:
        raise DataError(f"{path}: encoder weights do not match its config ({str(exc).splitlines()[0]})")
    encoder.to(map_location)
    encoder.eval()
    return encoder, ckpt
