"""Sub-pixel form of the decoders' (kernel 4, stride 2, padding 1) transposed convolutions.

Such a transposed convolution is the same linear map as one stride-1 convolution with 2^dim times the
output channels followed by one interleaving copy (:func:`subpixel_conv_t`); on channels-last memory
oneDNN runs it faster on CPU than the transposed convolution, and only the output rows a 3D column
keeps need computing.

In evaluation mode (:func:`run_eval`) a whole :func:`~lesscli.models.patch_decoder.upsampling_stack`
runs in this form. In training (:func:`run_train`) every layer computes its values in this form and its
gradients as the transposed convolution's own backward (:class:`_SubpixelConvT`), on channels-last
memory, each layer keeping only the rows the next one reads; differentiating through the sub-pixel
form itself is slower. All forms give the transposed convolutions' values and gradients to float32
rounding.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

# Sub-pixel form of a (kernel 4, stride 2, padding 1) transposed convolution, per axis: output j = 2m + r
# is input rows m - 1 + r and m + r times kernel taps SUBPIXEL_TAPS[r], i.e. a kernel-2 convolution at
# window m + r. Its phase blocks are stored by s = 1 - r, so that output j is window (j + 1) // 2 of block
# (j + 1) % 2: a plain pixel shuffle of the windows, shifted by one.
SUBPIXEL_TAPS = ((3, 1), (2, 0))
# Training's weight and bias gradients are summed over chunks of about this many input positions (samples x
# spatial ones): one channels-last call over a whole batch accumulates long float32 sums with several times
# the plain layout's rounding error (1e-5 relative on the headline columns); summed chunks bring it back to
# the plain layout's level at nearly the channels-last speed.
WEIGHT_GRAD_POSITIONS = 8192


def subpixel_weights(conv_t: nn.Module) -> tuple[Tensor, Tensor]:
    """The kernel-2 stride-1 convolution equal to a (kernel 4, stride 2, padding 1) transposed one.

    Returns:
        weight (2^dim * C_out, C_in, 2, ...) with one C_out block per phase (s_0, s_1, ...), s = 1 - r,
        and the bias repeated per block.
    """
    w = conv_t.weight                                        # (C_in, C_out, 4, ...)
    dim = w.dim() - 2
    if (conv_t.kernel_size, conv_t.stride, conv_t.padding) != ((4,) * dim, (2,) * dim, (1,) * dim):
        raise ValueError(f"sub-pixel form needs kernel 4, stride 2, padding 1, got {conv_t}")
    c_in, c_out = w.shape[:2]
    flat = torch.tensor([k for r in (1, 0) for k in SUBPIXEL_TAPS[r]], device=w.device)
    for axis in range(dim):
        w = w.index_select(2 + axis, flat)                   # axis index s * 2 + tap
    w = w.reshape(c_in, c_out, *[2] * (2 * dim))             # (C_in, C_out, s_0, tap_0, s_1, tap_1, ...)
    phases, taps = list(range(2, 2 + 2 * dim, 2)), list(range(3, 3 + 2 * dim, 2))
    w = w.permute(*phases, 1, 0, *taps).reshape(2**dim * c_out, c_in, *[2] * dim)
    return w.contiguous(), conv_t.bias.repeat(2**dim)


def _phases(x: Tensor, weight: Tensor, bias: Tensor, padding: int) -> Tensor:
    """Sub-pixel convolution of x (N, C_in, L_0, ...) given with one zero row on both ends of every
    spatial axis (``padding=0``) or without (``padding=1``: the convolution pads).

    Returns:
        (N, L_0 + 1, ..., 2, ..., C_out): window m of phase block s per axis, which is output 2m + s - 1
        of the transposed convolution (outputs -1 and 2L, which it crops, included).
    """
    dim = x.dim() - 2
    y = _CONV[dim](x, weight, bias, padding=padding)
    return y.movedim(1, -1).reshape(*y.shape[:1], *y.shape[2:], *[2] * dim, weight.shape[0] // 2**dim)


def _interleaved(ph: Tensor, windows0: int, channels_last: bool) -> Tensor:
    """Phases (N, w_0, ..., 2, ..., C) -> (N, C, 2 windows0, 2 w_1, ...), one copy of the first windows0
    into channels-last (the next convolution's, the stream canvas's) or plain (the batch canvas's)
    memory. The channels-last copy moves runs of 2 x C contiguous values, the plain one single values."""
    dim = (ph.dim() - 2) // 2
    n, windows, c = ph.shape[0], [windows0, *ph.shape[2:1 + dim]], ph.shape[-1]
    spatial = [v for w in windows for v in (w, 2)]
    order = [v for a in range(dim) for v in (1 + a, 1 + dim + a)]           # (window, phase) per axis
    if channels_last:
        out = ph.new_empty(n, *[2 * w for w in windows], c)
        out.view(n, *spatial, c).copy_(ph[:, :windows0].permute(0, *order, -1))
        return out.movedim(-1, 1)
    out = ph.new_empty(n, c, *[2 * w for w in windows])
    out.view(n, c, *spatial).copy_(ph[:, :windows0].permute(0, -1, *order))
    return out


def _hidden_layer(x: Tensor, conv_t: nn.Module, act: nn.Module, rows: int | None, padding: int) -> Tensor:
    """act(conv_t(x)) for x with its zero rows (``padding=0``) or without (1); returns the output with
    one zero row on both ends of every axis (only its first ``rows`` rows along axis 0 or more, None:
    all), channels-last."""
    # elementwise: before the shuffle
    ph = act(_phases(x, *subpixel_weights(conv_t), padding))
    windows = ph.shape[1]
    out = _interleaved(ph, windows if rows is None else min(windows, -(-rows // 2)), channels_last=True)
    for axis in range(2, out.dim()):                                         # the rows conv_t crops -> 0
        out.select(axis, 0).zero_()
        if axis > 2 or out.shape[2] == 2 * windows:
            out.select(axis, -1).zero_()
    return out


def _last_layer(x: Tensor, weight: Tensor, bias: Tensor, keep: int | None, padding: int,
                channels_last: bool = False) -> Tensor:
    """conv_t(x)[:, :, :keep] for x with its zero rows (``padding=0``; rows beyond those the kept
    outputs read are ignored) or without (1), in plain or channels-last memory."""
    ph = _phases(x, weight, bias, padding)
    lengths = [w - 1 for w in ph.shape[1:ph.dim() // 2]]                    # input rows, per axis
    rows = 2 * lengths[0] if keep is None else min(keep, 2 * lengths[0])
    out = _interleaved(ph, min(ph.shape[1], rows // 2 + 1), channels_last)
    return out[(slice(None), slice(None), slice(1, 1 + rows)) + tuple(slice(1, -1) for _ in lengths[1:])]


def subpixel_conv_t(x: Tensor, weight: Tensor, bias: Tensor, keep: int | None = None) -> Tensor:
    """Apply a transposed convolution given by :func:`subpixel_weights` to x (N, C_in, L_0, ...).

    The convolution runs on channels-last memory (oneDNN's fast layout for a few channels), padding x
    by one zero on each side; one permuting copy interleaves the phases into an (N, C_out, ...) result.

    Args:
        keep: output rows to keep along the first spatial axis (None or >= 2 * L_0: all 2 * L_0).

    Returns:
        (N, C_out, min(keep, 2 * L_0), 2 * L_1, ...), the transposed convolution's output (cropped).
    """
    return _last_layer(to_channels_last(x), weight, bias, keep, padding=1)


_CONV = {1: F.conv1d, 2: F.conv2d, 3: F.conv3d}
_CHANNELS_LAST = {4: torch.channels_last, 5: torch.channels_last_3d}


def to_channels_last(x: Tensor) -> Tensor:
    """x (N, C, ...) in channels-last memory (2D and 3D maps; a 1D map as it is)."""
    fmt = _CHANNELS_LAST.get(x.dim())
    return x if fmt is None else x.contiguous(memory_format=fmt)


def run_eval(stack: nn.Sequential, x: Tensor, keep: int | None = None, channels_last: bool = False) -> Tensor:
    """``stack(x)[:, :, :keep]`` for an :func:`upsampling_stack`, in its faster evaluation form (in
    channels-last memory with ``channels_last``).

    The first hidden layer runs as a transposed convolution (its sub-pixel form would compute the
    output rows it crops too: (L + 1)^dim windows for L^dim inputs, nearly twice the work on the 4 x 4
    x 4 first map), every later layer in sub-pixel form (a stride-1 convolution, its weights rearranged
    per call), all on channels-last memory: each sub-pixel hidden layer's output is interleaved straight
    into the zero-bordered input of the next, with the activation applied before the shuffle, and the
    layer before the last keeps only the rows the kept outputs read.
    """
    *hidden, last = list(stack)
    x = to_channels_last(x)
    padding = 1                                                  # x carries no zero rows yet
    for i, block in enumerate(hidden):
        if i == 0:
            x = block(x)
            continue
        rows = -(-keep // 2) + 2 if keep is not None and i == len(hidden) - 1 else None
        x, padding = _hidden_layer(x, *block, rows, padding), 0
    return _last_layer(x, *subpixel_weights(last), keep, padding, channels_last)


class _SubpixelConvT(torch.autograd.Function):
    """``conv_t(x)[:, :, :keep]`` (x channels-last) computed by :func:`_last_layer` into channels-last
    memory; its backward is the transposed convolution's (``aten.convolution_backward``, the one
    autograd runs for the module), the cropped rows' gradient being zero."""

    @staticmethod
    def forward(ctx, x: Tensor, weight: Tensor, bias: Tensor, conv_t: nn.Module, keep: int | None) -> Tensor:
        ctx.save_for_backward(x, weight)
        ctx.geometry = (conv_t.stride, conv_t.padding, conv_t.dilation, conv_t.output_padding)
        return _last_layer(x, *subpixel_weights(conv_t), keep, padding=1, channels_last=True)

    @staticmethod
    def backward(ctx, grad: Tensor):
        x, weight = ctx.saved_tensors
        stride, padding, dilation, output_padding = ctx.geometry
        rows, fmt = 2 * x.shape[2], _CHANNELS_LAST.get(grad.dim(), torch.contiguous_format)
        if grad.shape[2] == rows:
            full = grad.contiguous(memory_format=fmt)
        else:                                                # the cropped rows' gradient: 0
            full = torch.empty(*grad.shape[:2], rows, *grad.shape[3:], dtype=grad.dtype, device=grad.device,
                               memory_format=fmt)
            full[:, :, grad.shape[2]:].zero_()
            full[:, :, :grad.shape[2]].copy_(grad)
        needs, geometry = ctx.needs_input_grad, (list(stride), list(padding), list(dilation), True,
                                                 list(output_padding), 1)
        backward = torch.ops.aten.convolution_backward
        grad_x = backward(full, x, weight, None, *geometry, [True, False, False])[0] if needs[0] else None
        sums = [None, None]                                  # weight, bias: over chunks of the batch
        step = max(1, WEIGHT_GRAD_POSITIONS // math.prod(x.shape[2:]))
        for x_part, full_part in zip(x.split(step), full.split(step)) if needs[1] or needs[2] else ():
            parts = backward(full_part, x_part, weight, [weight.shape[1]], *geometry,
                             [False, needs[1], needs[2]])
            for i, part in enumerate(parts[1:]):
                if part is not None:
                    sums[i] = part if sums[i] is None else sums[i] + part
        return grad_x, *sums, None, None


def run_train(stack: nn.Sequential, x: Tensor, keep: int | None = None) -> Tensor:
    """``stack(x)[:, :, :keep]`` for an :func:`~lesscli.models.patch_decoder.upsampling_stack`,
    differentiable, in channels-last memory: every transposed convolution as a :class:`_SubpixelConvT`
    keeping only the rows the layers after it read (the first k output rows read the first k // 2 + 1
    input rows).
    """
    *hidden, last = list(stack)
    keeps = [keep]
    for _ in hidden:
        keeps.insert(0, None if keeps[0] is None else keeps[0] // 2 + 1)
    x = to_channels_last(x)
    for (conv_t, act), rows in zip(hidden, keeps):
        x = act(_SubpixelConvT.apply(x, conv_t.weight, conv_t.bias, conv_t, rows))
    return _SubpixelConvT.apply(x, last.weight, last.bias, last, keeps[-1])
