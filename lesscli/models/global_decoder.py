"""GLOBAL baseline image decoder: one state vector -> a whole 2D image or 3D volume of logits.

The single representation (``ParticleStates`` with P = 1) is layer-normalised, mapped by a linear
layer to a small feature map and upsampled by transposed convolutions to the training grid's shape. On a
grid of another shape (e.g. a larger phantom) the logits are resampled to it: the baseline has no notion of
position, which is exactly its weakness on the ``large`` set.

The norm matters for wide states: ``global-taxel`` reads 1,792 numbers, a third of them the map's
evidence (``log1p`` of a weight, never negative). Without it the common offset moves every first-layer
unit of every scan alike under Adam, and at lr 1e-2 its fits stalled or collapsed to background
(docs/results/fair-reproduction.md). Checkpoints written before the norm have no ``input_norm`` setting
and load without it.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lesscli.models.patch_decoder import BASE_PX, upsampling_stack
from lesscli.types import ImageGrid


class GlobalDecoder(nn.Module):
    """Vector -> (C, D, H, W) logits.

    Args:
        d_z: state width.
        n_classes: C.
        dim: 2 (image, D = 1) or 3 (volume).
        shape: (D, H, W) of the training grid; H and W should be 4 * 2^k (others are resampled).
        width: channels of the first feature map.
        input_norm: layer-normalise the state before the first layer (every fit since the norm; off for
            the checkpoints written before it).
    """

    @staticmethod
    def grid_settings(grid, patch_px: int, stitch: str, context: int = 0) -> dict:
        """Constructor arguments that follow from the training grid (patches, stitching and neighbour
        context do not apply), and the input norm every new fit gets."""
        return {"shape": [int(v) for v in grid.shape], "input_norm": True}

    def __init__(self, d_z: int, n_classes: int = 4, dim: int = 2,
                 shape: tuple[int, int, int] = (1, 128, 128), width: int = 64,
                 input_norm: bool = False) -> None:
        super().__init__()
        if dim not in (2, 3):
            raise ValueError(f"global decoder needs dim 2 or 3, got {dim}")
        self.dim, self.width, self.n_classes = dim, width, n_classes
        self.shape = tuple(int(s) for s in shape) if dim == 3 else (1, *map(int, shape[1:]))
        n_up = max(1, round(math.log2(max(self.shape[1:]) / BASE_PX)))
        if dim == 2:
            strides = [(2, 2)] * n_up
            self.base_depth = 1
        else:
            n_depth = min(n_up, max(0, math.ceil(math.log2(max(self.shape[0], 1) / BASE_PX))))
            strides = [(2, 2, 2)] * n_depth + [(1, 2, 2)] * (n_up - n_depth)
            self.base_depth = BASE_PX
        self.norm = nn.LayerNorm(d_z) if input_norm else nn.Identity()
        self.inp = nn.Linear(d_z, width * self.base_depth * BASE_PX * BASE_PX)
        self.up = upsampling_stack(dim, width, n_classes, strides)

    def forward(self, states, grid: ImageGrid) -> Tensor:
        """Decode the first (only) particle's state.

        Args:
            states: ParticleStates with ``z`` (B, 1, d_z).
            grid: output grid; its (D, H, W) sets the output shape.

        Returns:
            (B, C, D, H, W) float32 logits.
        """
        z = states.z[:, 0]
        b = z.shape[0]
        h = self.inp(self.norm(z))
        if self.dim == 2:
            out = self.up(h.view(b, self.width, BASE_PX, BASE_PX))[:, :, None]
        else:
            out = self.up(h.view(b, self.width, self.base_depth, BASE_PX, BASE_PX))
        if tuple(out.shape[2:]) != tuple(grid.shape):
            out = F.interpolate(out, size=tuple(grid.shape), mode="trilinear", align_corners=False)
        return out.to(torch.float32)
