"""Self-supervised force-prediction loss, averaged over particles.

For each particle that saw n >= 1 steps: K input slots and K' query slots are drawn uniformly
without replacement from its n real steps (all of them when n < K); the loss is the mean squared
error (over force features) of the force predicted at each query pose from the state after each
input step, averaged over the K x K' pairs, then over particles. Particles that saw nothing
contribute nothing; a batch where no particle saw anything gives a zero loss that still depends on
the parameters, so gradients are finite (zero).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor, nn

from lesscli.models.encoders import ParticleSequence

K_INPUT, K_QUERY = 16, 16


def sample_slots(mask: Tensor, k: int, generator: torch.Generator | None) -> tuple[Tensor, Tensor]:
    """Draw up to ``k`` real slots per row, uniformly without replacement.

    Args:
        mask: (N, C) bool, real slots (a prefix of each row).
        k: slots to draw.
        generator: random stream (CPU); None uses a fixed stream seeded with 0.

    Returns:
        index (N, k') long and ok (N, k') bool with k' = min(k, C); ``ok`` is False where a row has
        fewer than k' real slots (the index there repeats a real slot and must be ignored).
    """
    if generator is None:
        generator = torch.Generator().manual_seed(0)
    n, c = mask.shape
    keys = torch.rand(n, c, generator=generator).to(mask.device)
    keys = torch.where(mask, keys, torch.full_like(keys, 2.0))          # padding sorts last
    k = min(k, c)
    index = keys.topk(k, dim=1, largest=False).indices                  # (N, k)
    ok = torch.arange(k, device=mask.device)[None, :] < mask.sum(1, keepdim=True)
    return index, ok


def _take(values: Tensor, index: Tensor) -> Tensor:
    """values (N, C, D), index (N, k) -> (N, k, D)."""
    return values.gather(1, index[..., None].expand(-1, -1, values.shape[-1]))


def ssl_loss(seq: ParticleSequence, decoder: nn.Module, generator: torch.Generator | None,
             k_input: int = K_INPUT, k_query: int = K_QUERY, baseline: bool = False,
             states_at: Callable[[Tensor], Tensor] | None = None) -> Tensor:
    """Force-prediction MSE averaged over the particles that saw something.

    Args:
        seq: encoder output for the seen particles (with states ``z``, or without and ``states_at``).
        decoder: :class:`~lesscli.models.force_decoder.ForceDecoder`.
        generator: random stream for the slot draws.
        k_input: K, states per particle.
        k_query: K', query steps per particle.
        baseline: score the predict-the-mean baseline (prediction 0 in normalised units) on the
            same draws instead of the decoder.
        states_at: (N, K) input slots -> (N, K, d_z) states after them, used instead of ``seq.z`` (the
            encoder then runs each row only up to its last drawn slot; none at all for the baseline).

    Returns:
        Scalar tensor.
    """
    in_idx, in_ok = sample_slots(seq.mask, k_input, generator)
    q_idx, q_ok = sample_slots(seq.mask, k_query, generator)
    target = _take(seq.force, q_idx)                                    # (N, K', F)
    if baseline:
        pred = torch.zeros_like(target)[:, None]
    else:
        z = _take(seq.z, in_idx) if states_at is None else states_at(in_idx)
        pred = decoder(z, _take(seq.pose, q_idx))                       # (N, K, K', F)
    err = (pred - target[:, None]).pow(2).mean(-1)                      # (N, K, K')
    pair_ok = (in_ok[:, :, None] & q_ok[:, None, :]).to(err.dtype)
    if baseline:
        pair_ok = q_ok[:, None, :].to(err.dtype)
    per_particle = (err * pair_ok).sum((1, 2)) / pair_ok.sum((1, 2)).clamp(min=1.0)
    if per_particle.shape[0] == 0:
        anchor = seq.z.sum() if seq.z is not None else 0.0 if baseline else pred.sum()
        return err.sum() * 0.0 + anchor * 0.0
    return per_particle.mean()


class ForcePredictor(nn.Module):
    """Encoder + force decoder; ``forward(batch, generator)`` returns the SSL loss.

    The loss is computed inside ``forward`` so the module can be wrapped in
    DistributedDataParallel as is.
    """

    def __init__(self, encoder: nn.Module, decoder: nn.Module, k_input: int = K_INPUT,
                 k_query: int = K_QUERY) -> None:
        super().__init__()
        self.encoder = encoder
        self.decoder = decoder
        self.k_input, self.k_query = int(k_input), int(k_query)

    def forward(self, batch, generator: torch.Generator | None = None, baseline: bool = False) -> Tensor:
        seq = self.encoder.gather_sequence(batch)
        return ssl_loss(seq, self.decoder, generator, self.k_input, self.k_query, baseline=baseline,
                        states_at=lambda at: self.encoder.states_at(batch, seq, at))
