"""Frozen-encoder imaging fits: run the encoder once per scan and train the decoder on its states.

With the representation frozen, the encoder's ParticleStates of a scan are the same in every
epoch, so :func:`cache_states` computes them once (in evaluation mode, without gradients) and
:class:`CachedImager` decodes them. The wrapper shares the imager's ``encoder`` and ``decoder``
submodules, so its state dict has exactly the imager's keys and checkpoints stay interchangeable.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lesscli.data.image_labels import ImageDataset, collate_images
from lesscli.models.encoders import ParticleStates
from lesscli.models.imager import Imager
from lesscli.types import ImageGrid


class StatesDataset(torch.utils.data.Dataset):
    """Scan s -> its cached states and target.

    Args:
        z: (N, P, d_z) float32 final particle states per scan (CPU).
        seen: (N, P) bool, the particle saw at least one step.
        xy_mm: (P, 2) particle positions, mm (shared by all scans).
        targets: (N, D, H, W) long label codes.
    """

    def __init__(self, z: Tensor, seen: Tensor, xy_mm: Tensor, targets: Tensor) -> None:
        self.z, self.seen, self.xy_mm, self.targets = z, seen, xy_mm, targets

    def __len__(self) -> int:
        return int(self.z.shape[0])

    def __getitem__(self, s: int) -> dict:
        return {"z": self.z[s], "seen": self.seen[s], "xy_mm": self.xy_mm, "target": self.targets[s]}


class StatesBatch:
    """A batch of cached states (``inputs``: ParticleStates with z (B, P, d_z)) and targets (B, D, H, W)."""

    def __init__(self, inputs: ParticleStates, target: Tensor) -> None:
        self.inputs, self.target = inputs, target

    def to(self, device=None) -> StatesBatch:
        states = ParticleStates(z=self.inputs.z.to(device), xy_mm=self.inputs.xy_mm.to(device),
                                seen=self.inputs.seen.to(device))
        return StatesBatch(states, self.target.to(device))

    @property
    def size(self) -> int:
        return int(self.target.shape[0])


def collate_states(items: list[dict]) -> StatesBatch:
    states = ParticleStates(z=torch.stack([it["z"] for it in items]), xy_mm=items[0]["xy_mm"],
                            seen=torch.stack([it["seen"] for it in items]))
    return StatesBatch(states, torch.stack([it["target"] for it in items]))


def cache_states(imager: Imager, dataset: ImageDataset, batch_size: int,
                 device: torch.device) -> StatesDataset:
    """Run the (frozen) encoder over every scan of ``dataset`` once, in order, on ``device``.

    Returns:
        A :class:`StatesDataset` with the states and targets kept on the CPU.
    """
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, collate_fn=collate_images)
    encoder = imager.encoder.to(device)
    was_training = encoder.training
    encoder.eval()
    z, seen, targets, xy_mm = [], [], [], None
    with torch.no_grad():
        for batch in loader:
            states = encoder(batch.inputs.to(device))
            z.append(states.z.cpu())
            seen.append(states.seen.cpu())
            targets.append(batch.target)
            xy_mm = states.xy_mm.cpu()
    encoder.train(was_training)
    return StatesDataset(torch.cat(z), torch.cat(seen), xy_mm, torch.cat(targets))


class CachedImager(nn.Module):
    """An imager's decoder applied to cached ParticleStates; same submodules and state-dict keys.

    Args:
        imager: a frozen :class:`Imager` (its modules are shared, not copied).
    """

    def __init__(self, imager: Imager) -> None:
        super().__init__()
        self.encoder, self.decoder, self.grid = imager.encoder, imager.decoder, imager.grid

    def train(self, mode: bool = True) -> CachedImager:
        super().train(mode)
        self.encoder.eval()
        return self

    def forward(self, states: ParticleStates, grid: ImageGrid | None = None) -> Tensor:
        """ParticleStates (z: (B, P, d_z)) -> (B, C, D, H, W) float32 logits on ``grid``."""
        return self.decoder(states, grid or self.grid)
