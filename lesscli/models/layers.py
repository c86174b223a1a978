"""Small building blocks shared by the encoders and decoders (a leaf module: it imports no other model)."""

from __future__ import annotations

from torch import nn


def mlp(d_in: int, d_hidden: int, d_out: int) -> nn.Sequential:
    """Two-layer perceptron with a GELU (smooth, so finite-difference checks behave)."""
    return nn.Sequential(nn.Linear(d_in, d_hidden), nn.GELU(), nn.Linear(d_hidden, d_out))
