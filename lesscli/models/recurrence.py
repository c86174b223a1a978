"""A GRU over ragged rows that spends no work on padding.

Rows (particles) of very different lengths share one GRU. The input projection of every real step is
one matrix product; the recurrence then advances, at time t, only the rows that still have a step t:
rows are sorted by length (longest first), so they are a prefix of the sorted rows and each step is a
plain slice. The backward pass is written out (:class:`_Recurrence`): it touches the active rows of each
step only and forms the recurrent weights' gradient as one product over all steps (the library's packed
GRU on CPU allocates a zero gradient of the whole packed input at every time step, quadratic in length).

Same maths as ``torch.nn.GRU`` (gate order r, z, n; ``n = tanh(W_in x + b_in + r * (W_hn h + b_hn))``,
``h' = (h - n) * z + n``), to float rounding.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


def gru_gates(gi: Tensor, h: Tensor, weight_hh: Tensor, bias_hh: Tensor) -> tuple[Tensor, ...]:
    """One GRU step from precomputed input gates.

    Args:
        gi: (n, 3H) ``W_ih x + b_ih`` of the step.
        h: (n, H) states before the step.
        weight_hh, bias_hh: (3H, H) and (3H,).

    Returns:
        (n, H) states after the step, and what the backward pass needs: the reset and update gates
        (n, 2H), the candidate ``new`` (n, H) and ``W_hn h + b_hn`` (n, H).
    """
    gh = torch.addmm(bias_hh, h, weight_hh.t())
    two = 2 * h.shape[1]
    rz = torch.sigmoid(gi[:, :two] + gh[:, :two])
    reset, update = rz.chunk(2, 1)
    new = torch.tanh(torch.addcmul(gi[:, two:], reset, gh[:, two:]))
    return torch.addcmul(new, h - new, update), rz, new, gh[:, two:]


def _advance(gates: Tensor, weight_hh: Tensor, bias_hh: Tensor, sizes: list[int], keep: bool) -> tuple:
    """(S, H) states over time-major packed gates (step t: the first ``sizes[t]`` rows), and with ``keep``
    the gates, candidates and ``W_hn h + b_hn`` of every step for the backward pass (else None)."""
    hidden = weight_hh.shape[1]
    states = gates.new_empty(gates.shape[0], hidden)
    saved = (gates.new_empty(gates.shape[0], 2 * hidden), torch.empty_like(states),
             torch.empty_like(states)) \
        if keep else None
    h, at = gates.new_zeros(sizes[0], hidden), 0
    for size in sizes:
        span = slice(at, at + size)
        h, *parts = gru_gates(gates[span], h[:size], weight_hh, bias_hh)
        states[span] = h
        if keep:
            for buffer, part in zip(saved, parts):
                buffer[span] = part
        at += size
    return (states, *(saved or (None, None, None)))


class _Recurrence(torch.autograd.Function):
    """States of a GRU over time-major packed input gates: step t holds the first ``sizes[t]`` rows.

    The backward pass runs the recurrence in reverse for the state gradients and then forms the
    gradient of the recurrent weights as one matrix product over all steps (not one per step).
    """

    @staticmethod
    def forward(ctx, gates: Tensor, weight_hh: Tensor, bias_hh: Tensor, sizes: list[int]) -> Tensor:
        states, rz, new, ghn = _advance(gates, weight_hh, bias_hh, sizes, keep=True)
        ctx.sizes = sizes
        ctx.save_for_backward(weight_hh, states, rz, new, ghn)
        return states

    @staticmethod
    def backward(ctx, grad_states: Tensor):
        weight_hh, states, rz, new, ghn = ctx.saved_tensors
        sizes, hidden = ctx.sizes, weight_hh.shape[1]
        starts = [0]
        for size in sizes[:-1]:
            starts.append(starts[-1] + size)
        prev = torch.zeros_like(states)                                  # state before each step
        d_gh = grad_states.new_empty(states.shape[0], 3 * hidden)
        d_gi = torch.empty_like(d_gh)
        carry = None
        for t in range(len(sizes) - 1, -1, -1):
            span = slice(starts[t], starts[t] + sizes[t])
            g = grad_states[span].clone()
            if carry is not None:
                g[:carry.shape[0]] += carry
            h = states[starts[t - 1]:starts[t - 1] + sizes[t]] if t else prev[span]       # zeros at t = 0
            if t:
                prev[span] = h
            reset, update = rz[span].chunk(2, 1)
            d_new = g * (1 - update) * (1 - new[span] ** 2)
            d_rz = torch.cat([d_new * ghn[span], g * (h - new[span])], 1) * rz[span] * (1 - rz[span])
            d_gi[span] = torch.cat([d_rz, d_new], 1)
            d_gh[span] = torch.cat([d_rz, d_new * reset], 1)
            carry = torch.addmm(g * update, d_gh[span], weight_hh)
        return d_gi, d_gh.t() @ prev, d_gh.sum(0), None


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
    return ragged_gru_from_gates(gates, count, gru, x.shape[1])


def ragged_gru_from_gates(gates: Tensor, count: Tensor, gru: nn.GRU, length: int, last_only: bool = False,
                          at: Tensor | None = None) -> Tensor:
    """:func:`ragged_gru` from the input gates of the real steps.

    Args:
        gates: (S, 3H) ``W_ih x + b_ih`` of every real step, row by row in time order (S = count.sum()).
        count: (N,) long, real steps per row.
        gru: the GRU whose recurrent weights are used.
        length: C, slots per row in the output (>= count.max()).
        last_only: return only each row's state after its last real step, (N, H) (zeros where count is 0).
        at: (N, k) long, return only the states after these slots (each below its row's count), read
            straight from the packed states: no (N, C, H) tensor is formed.

    Returns:
        (N, C, H) the state after each real step; zeros past each row's count. (N, H) with ``last_only``,
        (N, k, H) with ``at``.
    """
    n, hidden = count.shape[0], gru.hidden_size
    shape = (n, at.shape[1], hidden) if at is not None else (n, hidden) if last_only else (n, length, hidden)
    if gates.shape[0] == 0:                 # no real step: still a function of the weights (zero gradients)
        return gates.new_zeros(shape) + (gates.sum() + sum(w.sum() for w in gru.parameters())) * 0.0
    count = count.to(gates.device)
    order = torch.argsort(count, descending=True, stable=True)
    alive = torch.bincount(count, minlength=length + 1).flip(0).cumsum(0).flip(0)[1:]   # rows with a step t
    sizes = [s for s in alive.tolist() if s > 0]
    steps = torch.repeat_interleave(torch.arange(len(sizes), device=gates.device), alive[:len(sizes)])
    rows = torch.cat([order[:s] for s in sizes])                      # time-major, longest rows first
    start = torch.cumsum(count, 0) - count
    args = (gates[start[rows] + steps], gru.weight_hh_l0, gru.bias_hh_l0, sizes)
    if torch.is_grad_enabled() and any(a.requires_grad for a in args[:3]):
        states = _Recurrence.apply(*args)
    else:
        states = _advance(*args, keep=False)[0]
    if at is not None:                      # packed position of (row, t): start of step t + the row's rank
        rank = torch.empty_like(order)
        rank[order] = torch.arange(n, device=order.device)
        starts = torch.cumsum(alive[:len(sizes)], 0) - alive[:len(sizes)]
        return states[starts[at] + rank[:, None]]
    out = gates.new_zeros(n if last_only else n * length, hidden)
    if last_only:
        last = steps == count[rows] - 1
        return out.index_put((rows[last],), states[last])
    return out.index_put((rows * length + steps,), states).view(shape)
