"""An imaging model: a (pretrained) encoder followed by an image decoder on a label grid.

``Imager(batch) -> (B, C, D, H, W)`` logits. The encoder is kept under the submodule name
``encoder`` so an imaging checkpoint can also be opened as a representation. With
``frozen=True`` the encoder's parameters do not require gradients and its forward runs without
building a graph.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lesscli.models.global_decoder import GlobalDecoder
from lesscli.models.patch_decoder import PatchDecoder
from lesscli.types import ImageGrid

DECODERS: dict[str, type] = {"patch": PatchDecoder, "global": GlobalDecoder}
# the decoder each encoder pairs with by default
DEFAULT_DECODER: dict[str, str] = {"less": "patch", "less-taxel": "patch", "global": "global",
                                   "global-taxel": "global"}


def grid_to_dict(grid: ImageGrid) -> dict:
    """Plain-value form for checkpoints."""
    return {"shape": list(grid.shape), "origin_mm": list(grid.origin_mm), "spacing_mm": list(grid.spacing_mm)}


def grid_from_dict(data: dict) -> ImageGrid:
    return ImageGrid(tuple(int(v) for v in data["shape"]), tuple(float(v) for v in data["origin_mm"]),
                     tuple(float(v) for v in data["spacing_mm"]))


class Imager(nn.Module):
    """Encoder + decoder + the grid it was trained on.

    Args:
        encoder: a module mapping a Batch to ParticleStates.
        decoder: PatchDecoder or GlobalDecoder.
        grid: the default output grid (the training label grid).
        frozen: keep the encoder fixed (no gradients, no graph).
        encoder_lr: when trained, the encoder's own learning rate (None: the decoder's).
    """

    def __init__(self, encoder: nn.Module, decoder: nn.Module, grid: ImageGrid, frozen: bool = True,
                 encoder_lr: float | None = None) -> None:
        super().__init__()
        self.encoder, self.decoder, self.grid = encoder, decoder, grid
        self.frozen, self.encoder_lr = frozen, encoder_lr
        if frozen:
            for p in self.encoder.parameters():
                p.requires_grad_(False)

    def train(self, mode: bool = True) -> Imager:
        super().train(mode)
        if self.frozen:
            self.encoder.eval()
        return self

    def param_groups(self, lr: float) -> list[dict]:
        """The optimiser's parameter groups: one at ``lr`` unless a trained encoder has its own rate."""
        trained = [p for p in self.parameters() if p.requires_grad]
        if self.frozen or self.encoder_lr is None:
            return [{"params": trained, "lr": lr}]
        encoder = {id(p) for p in self.encoder.parameters()}
        return [g for g in ({"params": [p for p in trained if id(p) not in encoder], "lr": lr},
                            {"params": [p for p in trained if id(p) in encoder], "lr": self.encoder_lr})
                if g["params"]]

    def states(self, batch):
        """The encoder's ParticleStates (no graph when frozen)."""
        if self.frozen:
            with torch.no_grad():
                return self.encoder(batch)
        return self.encoder(batch)

    def forward(self, batch, grid: ImageGrid | None = None) -> Tensor:
        """Batch -> (B, C, D, H, W) float32 logits on ``grid`` (default: the training grid)."""
        return self.decoder(self.states(batch), grid or self.grid)
