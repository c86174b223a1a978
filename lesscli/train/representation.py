"""Opening a representation checkpoint: the encoder a ``less pretrain`` file holds (an imaging checkpoint
holds one too), rebuilt from its config with its weights."""

from __future__ import annotations

import torch

from lesscli.errors import DataError
from lesscli.io.checkpoint import encoder_state, load_checkpoint
from lesscli.models.registry import build_encoder


def load_representation(path: str, map_location: str | torch.device = "cpu"):
    """Rebuild the encoder stored in the checkpoint at ``path``.

    Returns:
        (encoder, checkpoint): the encoder in eval mode with its weights loaded, and the checkpoint
        dict (``checkpoint["norm_stats"]`` normalises new data exactly as in training).

    Raises:
        DataError: naming ``path`` when it is no representation or its weights do not fit its config.
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
        raise DataError(f"{path}: encoder weights do not match its config "
                        f"({str(exc).splitlines()[0]})") from None
    encoder.to(map_location)
    encoder.eval()
    return encoder, ckpt
