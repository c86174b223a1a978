"""LESS image reconstruction: every particle state -> a patch of logits placed at the particle.

A shared transposed-convolution network maps each state to a patch of logits (2D: ``patch_px`` square;
3D: a full-depth column) at the training label grid's spacing. Patches are placed at their particle's
x-y in mm and overlapping logits summed (``stitch="mean"`` averages them); the caller takes the softmax.
Pixels no particle covers, and the patches of particles that saw nothing, keep logit 0: uniform
probabilities, maximum entropy, so untouched regions stay honestly uncertain.

``context=k`` (odd) adds a k x k convolution over the particle grid, so each patch also reads its
neighbours' states (still local); ``context=0`` is the paper's decoder. On a grid of another spacing
(``large``) patches are resampled to the same physical size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lesscli.models.subpixel import run_eval, run_train, to_channels_last
from lesscli.types import ImageGrid

PATCH_PX = 32               # in-plane patch side, pixels of the training grid
DEPTH_PX = 26               # depth of a 3D column, slices of the training grid
BASE_PX = 4                 # spatial side of the first feature map
SPACING_RTOL = 1e-6         # grids whose spacings agree this well need no resampling
CONTEXT_WIDTH = 32          # features the neighbour context adds to each state (context > 0)
STITCH_MODES = ("sum", "mean")


def _up_block(dim: int, c_in: int, c_out: int, stride, last: bool) -> nn.Module:
    conv_t = nn.ConvTranspose2d if dim == 2 else nn.ConvTranspose3d
    kernel = tuple(2 * s for s in stride)
    padding = tuple(s // 2 for s in stride)
    layer = conv_t(c_in, c_out, kernel_size=kernel, stride=stride, padding=padding)
    return layer if last else nn.Sequential(layer, nn.GELU())


def upsampling_stack(dim: int, width: int, n_classes: int, strides: list[tuple[int, ...]]) -> nn.Sequential:
    """Transposed convolutions, each multiplying the spatial size by its stride, halving channels."""
    blocks, c_in = [], width
    for i, stride in enumerate(strides):
        last = i == len(strides) - 1
        c_out = n_classes if last else max(c_in // 2, 8)
        blocks.append(_up_block(dim, c_in, c_out, stride, last))
        c_in = c_out
    return nn.Sequential(*blocks)


class PatchDecoder(nn.Module):
    """Shared transposed-conv decoder from particle states to placed, summed logit patches.

    Args:
        d_z: particle state width.
        n_classes: C.
        dim: 2 (patches) or 3 (full-depth columns).
        patch_px: in-plane patch side in pixels (a power of two times 4).
        depth_px: column depth in slices (3D only).
        patch_spacing_mm: dz, dy, dx of the pixels the patch is made in (the training grid's).
        width: channels of the first feature map.
        stitch: "sum" (the paper) or "mean" of overlapping patch logits.
        context: side k of the convolution over the particle grid whose features join each state
            (odd; 0: none, the paper's decoder).
        context_width: features it adds.
    """

    # Fast paths (lesscli.models.subpixel), each timed against the modules by ``less bench imaging``:
    subpixel_eval = True         # evaluation decodes in sub-pixel form
    subpixel_train = True        # training on the CPU decodes in sub-pixel form, with its own backward

    @staticmethod
    def grid_settings(grid: ImageGrid, patch_px: int, stitch: str, context: int = 0) -> dict:
        """Constructor arguments that follow from the training grid (and the image settings)."""
        out = {"patch_px": int(patch_px), "depth_px": int(grid.shape[0]),
               "patch_spacing_mm": [float(v) for v in grid.spacing_mm], "stitch": stitch}
        return {**out, "context": int(context)} if context else out

    def __init__(self, d_z: int, n_classes: int = 4, dim: int = 2, patch_px: int = PATCH_PX,
                 depth_px: int = DEPTH_PX,
                 patch_spacing_mm: tuple[float, float, float] = (0.9, 0.4774, 0.4774), width: int = 64,
                 stitch: str = "sum", context: int = 0, context_width: int = CONTEXT_WIDTH) -> None:
        super().__init__()
        if stitch not in STITCH_MODES:
            raise ValueError(f"stitch must be one of {STITCH_MODES}, got '{stitch}'")
        if context < 0 or (context and context % 2 == 0) or context_width < 1:
            raise ValueError(f"context must be 0 or odd and context_width >= 1, got {context}, "
                             f"{context_width}")
        self.stitch, self.context = stitch, int(context)
        self.neighbours = nn.Conv2d(d_z + 1, context_width, context,
                                    padding=context // 2) if context else None
        n_up = round(math.log2(patch_px / BASE_PX))
        if dim not in (2, 3) or BASE_PX * 2**n_up != patch_px or n_up < 1:
            raise ValueError(f"patch decoder needs dim 2 or 3 and patch_px = 4 * 2^k, k >= 1, got {dim}, "
                             f"{patch_px}")
        self.dim, self.n_classes, self.width = dim, n_classes, width
        self.patch_px, self.depth_px = patch_px, depth_px if dim == 3 else 1
        self.patch_spacing_mm = tuple(float(s) for s in patch_spacing_mm)
        self.base_depth = math.ceil(self.depth_px / 2**n_up) if dim == 3 else 1
        d_in = d_z + (context_width if context else 0)
        self.inp = nn.Linear(d_in, width * self.base_depth * BASE_PX * BASE_PX)
        stride = (2, 2) if dim == 2 else (2, 2, 2)
        self.up = upsampling_stack(dim, width, n_classes, [stride] * n_up)

    def with_context(self, z: Tensor, seen: Tensor) -> Tensor:
        """(B, P, d_z) states -> (B, P, d_in) decoder inputs: the states, and with ``context`` the
        neighbour features beside them (the particles must form a full square grid, row-major)."""
        if self.neighbours is None:
            return z
        b, p, _ = z.shape
        n = math.isqrt(p)
        if n * n != p:
            raise ValueError(f"neighbour context needs a square particle grid, got {p} particles")
        keep = seen.to(z.dtype)[..., None]
        grid = torch.cat([z * keep, keep], dim=-1).transpose(1, 2).reshape(b, -1, n, n)
        ctx = F.gelu(self.neighbours(grid)).reshape(b, -1, p).transpose(1, 2)
        return torch.cat([z, ctx], dim=-1)

    def patches(self, z: Tensor, channels_last: bool = False, seen: Tensor | None = None) -> Tensor:
        """(B, P, d_in) decoder inputs (:meth:`with_context`) -> (B, P, C, Dp, ph, pw) float32 logits
        (Dp = 1 in 2D).

        Args:
            channels_last: return them in channels-last memory (classes innermost, the stream
                canvas's layout; in evaluation mode at no extra cost); the same values.
            seen: (B, P) bool; in training mode only these particles' patches are decoded (the
                others are zeros, which :func:`place_patches` masks anyway). None: all.
        """
        b, p, _ = z.shape
        if self.training:
            flat = z.reshape(b * p, -1)
            if seen is None:
                out = self._decode_train(flat)
            else:
                rows = seen.reshape(-1).nonzero().squeeze(1).to(z.device)
                part = self._decode_train(flat.index_select(0, rows))
                out = part.new_zeros(b * p, *part.shape[1:])
                out.index_copy_(0, rows, part)
            out = to_channels_last(out) if channels_last else out.contiguous()
        else:
            out = self._decode_eval(z.reshape(b * p, -1), channels_last)
        out = out if self.dim == 3 else out[:, :, None]
        return out.reshape(b, p, *out.shape[1:]).to(torch.float32)

    def _first_map(self, z: Tensor) -> Tensor:
        """(N, d_in) -> (N, width, [base_depth,] BASE_PX, BASE_PX): the upsampling stack's input."""
        return self.inp(z).view(z.shape[0], self.width, *([self.base_depth] if self.dim == 3 else []),
                                BASE_PX, BASE_PX)

    def _keep(self) -> int | None:
        """Output depth rows to keep (a 3D column's depth; None in 2D)."""
        return self.depth_px if self.dim == 3 else None

    def _decode_eval(self, z: Tensor, channels_last: bool) -> Tensor:
        """(N, d_in) -> (N, C, [depth_px,] ph, pw) logits in evaluation: the modules, or with
        ``subpixel_eval`` :func:`run_eval` (the same values to float32 rounding)."""
        h, keep = self._first_map(z), self._keep()
        if not self.subpixel_eval:
            out = self.up(h)[:, :, :keep]
            return to_channels_last(out) if channels_last else out.contiguous()
        return run_eval(self.up, h, keep, channels_last)

    def _decode_train(self, z: Tensor) -> Tensor:
        """(N, d_in) -> (N, C, [depth_px,] ph, pw) differentiable logits: the modules, or with
        ``subpixel_train`` on the CPU :func:`run_train` (the same values and gradients to float32
        rounding)."""
        h, keep = self._first_map(z), self._keep()
        if not (self.subpixel_train and h.device.type == "cpu"):
            return self.up(h)[:, :, :keep]
        return run_train(self.up, h, keep)

    def forward(self, states, grid: ImageGrid) -> Tensor:
        """Decode and place.

        Args:
            states: ParticleStates with ``z`` (B, P, d_z), ``xy_mm`` (P, 2), ``seen`` (B, P).
            grid: the output grid.

        Returns:
            (B, C, D, H, W) float32 logits; 0 where no seen particle's patch reaches.
        """
        patches = self.patches(self.with_context(states.z, states.seen), seen=states.seen)
        return place_patches(patches, states.xy_mm, grid, self.patch_spacing_mm, states.seen, self.stitch)


def resample_patches(patches: Tensor, size: tuple[int, int, int]) -> Tensor:
    """(B, P, C, Dp, ph, pw) -> (B, P, C, *size), trilinear (identity when the size already matches)."""
    if tuple(patches.shape[3:]) == tuple(size):
        return patches
    b, p, c = patches.shape[:3]
    flat = patches.reshape(b * p, c, *patches.shape[3:])
    out = F.interpolate(flat, size=size, mode="trilinear", align_corners=False)
    return out.reshape(b, p, c, *size)


def target_patch_size(patch_shape: tuple[int, int, int], patch_spacing_mm,
                      grid: ImageGrid) -> tuple[int, int, int]:
    """Patch size in ``grid`` pixels with the same physical extent (columns span the grid's depth)."""
    depth = grid.shape[0] if patch_shape[0] > 1 or grid.shape[0] > 1 else 1
    sizes = [max(1, round(patch_shape[a] * patch_spacing_mm[a] / grid.spacing_mm[a])) for a in (1, 2)]
    same = all(math.isclose(patch_spacing_mm[a], grid.spacing_mm[a], rel_tol=SPACING_RTOL) for a in (1, 2))
    return (depth, *(patch_shape[1:] if same else sizes))


def padded_corners(xy_mm: Tensor, grid: ImageGrid, ph: int, pw: int) -> tuple[Tensor, Tensor]:
    """Top-left (row, col) of each particle's ph x pw patch on ``grid`` padded by a patch on every side.

    The patch is centred on the particle within half a pixel; patches wholly off the grid are clamped
    into the padding. (P,) long tensors on the CPU.
    """
    pix = grid.pixel_of(xy_mm.detach().to("cpu", torch.float64))
    _, h, w = grid.shape
    col0 = torch.round(pix[:, 0] - (pw - 1) / 2).long().clamp(-pw, w) + pw
    row0 = torch.round(pix[:, 1] - (ph - 1) / 2).long().clamp(-ph, h) + ph
    return row0, col0


def place_patches(patches: Tensor, xy_mm: Tensor, grid: ImageGrid,
                  patch_spacing_mm: tuple[float, float, float], seen: Tensor | None = None,
                  stitch: str = "sum") -> Tensor:
    """Sum patches into an image, each centred on its particle (within half a pixel).

    Args:
        patches: (B, P, C, Dp, ph, pw) logits at ``patch_spacing_mm``.
        xy_mm: (P, 2) particle x, y, mm.
        grid: output grid.
        patch_spacing_mm: dz, dy, dx of the patch pixels.
        seen: (B, P) bool; particles that saw nothing are left out. None keeps all.
        stitch: "sum" of overlapping logits, or their "mean" over the covering patches.

    Returns:
        (B, C, D, H, W) float32 summed logits.
    """
    h, w = grid.shape[1:]
    patches = resample_patches(patches, target_patch_size(tuple(patches.shape[3:]), patch_spacing_mm, grid))
    ph, pw = patches.shape[-2:]
    corners = list(zip(*(t.tolist() for t in padded_corners(xy_mm, grid, ph, pw))))
    keep = None if seen is None else seen.to(patches.device, patches.dtype)
    padded = (h + 2 * ph, w + 2 * pw)
    canvas = _Placed.apply(patches, keep, corners, padded)
    if stitch == "mean":
        ones = patches.new_ones(1, 1, 1, 1, ph, pw).expand(*patches.shape[:2], 1, 1, ph, pw)
        canvas = canvas / _Placed.apply(ones, keep, corners, padded).clamp_min(1.0)
    return canvas[..., ph:ph + h, pw:pw + w]


class _Placed(torch.autograd.Function):
    """Patches (B, P, C, D, ph, pw) times ``keep`` (B, P) (None: all 1) summed into a zero canvas
    (B, C, D, *padded) at their top-left ``corners`` [(row, col)] by one slice add per particle; the
    gradient of a patch is its slice of the canvas's gradient times its keep. A particle kept nowhere
    in the batch costs nothing.

    Autograd through the same slice adds keeps every intermediate canvas (seconds per backward at the
    default grid); one ``index_add`` over all pixels strides across the batch, class and depth axes
    for every pixel (``less bench imaging`` compares both).
    """

    @staticmethod
    def forward(ctx, patches: Tensor, keep: Tensor | None, corners: list, padded: tuple[int, int]) -> Tensor:
        b, _, c, d, ph, pw = patches.shape
        out = patches.new_zeros(b, c, d, *padded)
        weights = PatchWeights.of(keep, len(corners))
        for i, (row, col) in enumerate(corners):
            if weights.placed[i]:
                out[..., row:row + ph, col:col + pw] += weights.applied(patches[:, i], i)
        ctx.weights, ctx.corners, ctx.size = weights, corners, (ph, pw)
        return out

    @staticmethod
    def backward(ctx, grad: Tensor):
        ph, pw, weights = *ctx.size, ctx.weights
        parts = []
        for i, (row, col) in enumerate(ctx.corners):
            part = grad[..., row:row + ph, col:col + pw]
            parts.append(weights.applied(part, i) if weights.placed[i] else torch.zeros_like(part))
        return torch.stack(parts, dim=1), None, None, None


@dataclass
class PatchWeights:
    """How each particle's patch enters the canvas: the batch rows' ``keep`` weights, sorted per particle
    into the two cases that need no multiply.

    Attributes:
        placed: per particle, kept (weight not 0) in some batch row; an unplaced one costs nothing.
        whole: per particle, kept at weight 1 in every batch row.
        keep: (B, P) weights, None when all are 1.
    """

    placed: list[bool]
    whole: list[bool]
    keep: Tensor | None

    @classmethod
    def of(cls, keep: Tensor | None, n: int) -> PatchWeights:
        """The weights of ``n`` particles from ``keep`` (B, n) (None: all 1)."""
        if keep is None:
            return cls(placed=[True] * n, whole=[True] * n, keep=None)
        zeros = (keep == 0).all(0).tolist()
        return cls(placed=[not z for z in zeros], whole=(keep == 1).all(0).tolist(), keep=keep)

    def applied(self, x: Tensor, i: int) -> Tensor:
        """(B, ...) values of particle i's patch (or its gradient) times its batch rows' weights."""
        return x if self.whole[i] else x * self.keep[:, i, None, None, None, None]
