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
    i_r, i_z, i_n = gi.chunk(3, 1)
    h_r, h_z, h_n = gh.chunk(3, 1)
    reset = torch.sigmoid(i_r + h_r)
    update = torch.sigmoid(i_z + h_z)
    new = torch.tanh(i_n + reset * h_n)
    return (h - new) * update + new


def ragged_gru(x: Tensor, count: Tensor, gru: nn.GRU) -> Tensor:
    """A one-layer batch-first GRU over each row's first ``count`` steps, from a zero state.

    Args:
        x: (N, C, D) inputs; slots past a row's count are never read.
        count: (N,) long, real steps per row (0 allowed).
        gru: the ``nn.GRU`` whose weights are used (one layer, unidirectional).

    Returns:
        (N, C, H) the state after each real step; zeros past each row's count.
    """
    n, c, _ = x.shape
    hidden = gru.hidden_size
    out = x.new_zeros(n * c, hidden)
    count = count.to(x.device)
    if n == 0 or c == 0 or not bool((count > 0).any()):       # still a function of the weights (zero gradients)
        return out.view(n, c, hidden) + (x.sum() + sum(w.sum() for w in gru.parameters())) * 0.0
    order = torch.argsort(count, descending=True, stable=True)
    active = torch.bincount(count.clamp(max=c), minlength=c + 1).flip(0).cumsum(0).flip(0)[1:]   # rows alive at t
    sizes = active.tolist()
    sizes = sizes[:sum(1 for s in sizes if s > 0)]
    steps = torch.repeat_interleave(torch.arange(len(sizes), device=x.device), active[:len(sizes)])
    rows = torch.cat([order[:s] for s in sizes])
    flat = rows * c + steps                                          # time-major packed positions
    gi = torch.addmm(gru.bias_ih_l0, x.reshape(n * c, -1)[flat], gru.weight_ih_l0.t())
    h = x.new_zeros(sizes[0], hidden)
    states = []
    for t, g in enumerate(gi.split(sizes)):
        h = gru_gates(g, h[:sizes[t]], gru.weight_hh_l0, gru.bias_hh_l0)
        states.append(h)
    return out.index_put((flat,), torch.cat(states)).view(n, c, hidden)
