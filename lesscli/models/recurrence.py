"""A GRU over ragged rows that spends no work on padding.

Rows (particles) of very different lengths share one GRU. The input projection of every real step is
one matrix product; the recurrence then advances, at time t, only the rows that still have a step t:
rows are sorted by length (longest first), so they are a prefix of the sorted rows and each step is a
plain slice. Autograd then keeps per-step tensors of the active rows only (the library's packed GRU
on CPU allocates a zero gradient of the whole packed input at every time step, quadratic in length).

Same maths as ``torch.nn.GRU`` (gate order r, z, n; ``n = tanh(W_in x + b_in + r * (W_hn h + b_hn))``,
``h' = (h - n) * z + n``), to float rounding.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


def gru_gates(gi: Tensor, h: Tensor, weight_hh: Tensor, bias_hh: Tensor) -> Tensor:
    """One GRU step from precomputed input gates.

    Args:
        gi: (n, 3H) ``W_ih x + b_ih`` of the step.
        h: (n, H) states before the step.
        weight_hh, bias_hh: (3H, H) and (3H,).

    Returns:
        (n, H) states after the step.
    """
    gh = torch.addmm(bias_hh, h, weight_hh.t())
    two = 2 * h.shape[1]
    reset, update = torch.sigmoid(gi[:, :two] + gh[:, :two]).chunk(2, 1)
    new = torch.tanh(torch.addcmul(gi[:, two:], reset, gh[:, two:]))
    return torch.addcmul(new, h - new, update)


def ragged_gru(x: Tensor, count: Tensor, gru: nn.GRU) -> Tensor:
    """A one-layer batch-first GRU over each row's first ``count`` steps, from a zero state.

    Args:
        x: (N, C, D) inputs; slots past a row's count are never read.
        count: (N,) long, real steps per row (0 allowed).
        gru: the ``nn.GRU`` whose weights are used (one layer, unidirectional).

    Returns:
        (N, C, H) the state after each real step; zeros past each row's count.
    """
    real = torch.arange(x.shape[1], device=x.device) < count.to(x.device)[:, None]
    gates = torch.addmm(gru.bias_ih_l0, x[real], gru.weight_ih_l0.t())
    return ragged_gru_from_gates(gates, count, gru, x.shape[1]) + x.sum() * 0.0   # x always in the graph


def ragged_gru_from_gates(gates: Tensor, count: Tensor, gru: nn.GRU, length: int) -> Tensor:
    """:func:`ragged_gru` from the input gates of the real steps.

    Args:
        gates: (S, 3H) ``W_ih x + b_ih`` of every real step, row by row in time order (S = count.sum()).
        count: (N,) long, real steps per row.
        gru: the GRU whose recurrent weights are used.
        length: C, slots per row in the output (>= count.max()).

    Returns:
        (N, C, H) the state after each real step; zeros past each row's count.
    """
    n, hidden = count.shape[0], gru.hidden_size
    out = gates.new_zeros(n * length, hidden)
    if gates.shape[0] == 0:                 # no real step: still a function of the weights (zero gradients)
        return out.view(n, length, hidden) + (gates.sum() + sum(w.sum() for w in gru.parameters())) * 0.0
    count = count.to(gates.device)
    order = torch.argsort(count, descending=True, stable=True)
    alive = torch.bincount(count, minlength=length + 1).flip(0).cumsum(0).flip(0)[1:]   # rows with a step t
    sizes = [s for s in alive.tolist() if s > 0]
    steps = torch.repeat_interleave(torch.arange(len(sizes), device=gates.device), alive[:len(sizes)])
    rows = torch.cat([order[:s] for s in sizes])                      # time-major, longest rows first
    start = torch.cumsum(count, 0) - count
    h = gates.new_zeros(sizes[0], hidden)
    states = []
    for t, g in enumerate(gates[start[rows] + steps].split(sizes)):
        h = gru_gates(g, h[:sizes[t]], gru.weight_hh_l0, gru.bias_hh_l0)
        states.append(h)
    return out.index_put((rows * length + steps,), torch.cat(states)).view(n, length, hidden)
