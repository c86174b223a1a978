"""Patch stitching and decoders: placement in millimetres, uncovered pixels, shapes, gradients."""

import math
from types import SimpleNamespace

import pytest
import torch

from lesscli.models.global_decoder import GlobalDecoder
from lesscli.models.patch_decoder import PatchDecoder, place_patches
from lesscli.types import ImageGrid

SPACING = (0.9, 0.4774, 0.4774)


def _grid(shape=(1, 64, 64), spacing=SPACING):
    d, h, w = shape
    return ImageGrid(shape, (-(d - 1) * spacing[0], -(h - 1) / 2 * spacing[1], -(w - 1) / 2 * spacing[2]),
                     spacing)


def _pixel_xy_mm(grid):
    ys = grid.origin_mm[1] + grid.spacing_mm[1] * torch.arange(grid.shape[1], dtype=torch.float64)
    xs = grid.origin_mm[2] + grid.spacing_mm[2] * torch.arange(grid.shape[2], dtype=torch.float64)
    return torch.meshgrid(ys, xs, indexing="ij")


def _states(z, xy_mm, seen=None):
    seen = torch.ones(z.shape[:2], dtype=torch.bool) if seen is None else seen
    return SimpleNamespace(z=z, xy_mm=xy_mm, seen=seen)


@pytest.mark.parametrize("xy", [(0.0, 0.0), (3.3, -4.1), (-7.77, 5.05), (12.2, 0.24)])
def test_symmetric_patch_centred_on_particle(xy):
    grid = _grid()
    k = torch.arange(32, dtype=torch.float64) - 15.5
    bump = torch.exp(-(k[:, None] ** 2 + k[None, :] ** 2) / 20.0)
    patches = torch.zeros(1, 1, 2, 1, 32, 32, dtype=torch.float64)
    patches[0, 0, 1, 0] = bump
    out = place_patches(patches, torch.tensor([xy]), grid, SPACING)[0, 1, 0]
    yy, xx = _pixel_xy_mm(grid)
    cx, cy = (out * xx).sum() / out.sum(), (out * yy).sum() / out.sum()
    assert abs(cx - xy[0]) <= SPACING[2] / 2 + 1e-9
    assert abs(cy - xy[1]) <= SPACING[1] / 2 + 1e-9


@pytest.mark.parametrize("dim", [2, 3])
def test_one_hot_state_lands_centred_and_rest_is_max_entropy(dim):
    torch.manual_seed(0)
    shape = (1, 80, 80) if dim == 2 else (6, 80, 80)
    dec = PatchDecoder(d_z=8, n_classes=4, dim=dim, depth_px=shape[0], width=16)
    xy = torch.tensor([[-6.0, -6.0], [5.3, 2.9], [6.0, -6.0]])
    z = torch.zeros(1, 3, 8)
    z[0, 1, 3] = 1.0                                     # one-hot state for particle 1
    seen = torch.tensor([[False, True, False]])          # the others saw nothing
    grid = _grid(shape)
    logits = dec(_states(z, xy, seen), grid)
    assert logits.shape == (1, 4, *shape)
    covered = (logits != 0).any(dim=1).any(dim=0)[0] if dim == 2 else (logits != 0).any(dim=1)[0].any(dim=0)
    rows = torch.nonzero(covered.any(dim=1)).flatten()
    cols = torch.nonzero(covered.any(dim=0)).flatten()
    assert len(rows) == 32 and len(cols) == 32
    yy, xx = _pixel_xy_mm(grid)
    centre_x = (xx[0, cols[0]] + xx[0, cols[-1]]) / 2
    centre_y = (yy[rows[0], 0] + yy[rows[-1], 0]) / 2
    assert abs(centre_x - 5.3) <= SPACING[2] / 2 and abs(centre_y - 2.9) <= SPACING[1] / 2
    probs = torch.softmax(logits, dim=1)
    ent = -(probs * torch.log(probs)).sum(dim=1)[0]
    assert torch.allclose(ent[:, ~covered], torch.tensor(math.log(4.0)))
    assert ent[:, covered].max() < math.log(4.0)


def test_overlapping_patches_sum():
    grid = _grid((1, 40, 40))
    patches = torch.ones(1, 2, 1, 1, 8, 8)
    out = place_patches(patches, torch.tensor([[0.0, 0.0], [1.0, 0.0]]), grid, SPACING)
    assert out.max() == 2 and out.sum() == 128


def test_mean_stitch_averages_over_covering_patches():
    grid = _grid((1, 40, 40))
    patches = torch.ones(1, 2, 1, 1, 8, 8)
    patches[0, 1] = 3.0
    out = place_patches(patches, torch.tensor([[0.0, 0.0], [1.0, 0.0]]), grid, SPACING, stitch="mean")
    assert set(out.unique().tolist()) == {0.0, 1.0, 2.0, 3.0}
    seen = torch.tensor([[True, False]])
    out = place_patches(patches, torch.tensor([[0.0, 0.0], [1.0, 0.0]]), grid, SPACING, seen, stitch="mean")
    assert set(out.unique().tolist()) == {0.0, 1.0} and out.sum() == 64


def test_patches_outside_the_grid_are_dropped():
    grid = _grid((1, 16, 16))
    patches = torch.ones(1, 2, 1, 1, 8, 8)
    out = place_patches(patches, torch.tensor([[100.0, 0.0], [0.0, 3.5]]), grid, SPACING)
    # particle 0 is far outside; particle 1 straddles the top edge: 8 columns x (rows inside)
    assert out.sum() > 0 and out.sum() < 64
    assert out.shape == (1, 1, 1, 16, 16)


@pytest.mark.parametrize("stitch", ["sum", "mean"])
def test_placement_gradient_is_the_adjoint_of_the_slice_adds(stitch):
    """The placement's own backward against finite differences (float64), with overlapping patches,
    one straddling the edge, one off the grid and one unseen."""
    grid = _grid((2, 12, 12))
    xy = torch.tensor([[0.0, 0.0], [1.1, -0.6], [2.9, 2.4], [100.0, 0.0]])
    seen = torch.tensor([[True, True, True, False]])
    patches = torch.randn(1, 4, 2, 2, 8, 8, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda p: place_patches(p, xy, grid, SPACING, seen, stitch), (patches,))


def test_coarser_grid_keeps_physical_patch_size():
    coarse = (0.9, 2 * SPACING[1], 2 * SPACING[2])
    grid = _grid((1, 40, 40), coarse)
    patches = torch.ones(1, 1, 1, 1, 32, 32)
    out = place_patches(patches, torch.tensor([[0.0, 0.0]]), grid, SPACING)
    covered = out[0, 0, 0] > 0
    assert covered.any(dim=0).sum() == 16 and covered.any(dim=1).sum() == 16


def test_gradients_reach_every_seen_patch():
    dec = PatchDecoder(d_z=4, n_classes=3, dim=2, width=8)
    z = torch.randn(2, 3, 4, requires_grad=True)
    seen = torch.tensor([[True, True, False], [True, False, True]])
    logits = dec(_states(z, torch.tensor([[0.0, 0.0], [8.0, 0.0], [-8.0, 0.0]]), seen), _grid())
    logits.square().sum().backward()
    assert torch.equal(z.grad.abs().sum(-1) > 0, seen)


@pytest.mark.parametrize("dim,shape", [(2, (1, 128, 128)), (3, (26, 128, 128))])
def test_global_decoder_shapes(dim, shape):
    dec = GlobalDecoder(d_z=8, n_classes=4, dim=dim, shape=shape, width=16)
    z = torch.randn(2, 1, 8)
    states = _states(z, torch.zeros(1, 2))
    assert dec(states, _grid(shape)).shape == (2, 4, *shape)
    assert dec(states, _grid((shape[0], 64, 64))).shape == (2, 4, shape[0], 64, 64)


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("keep", [None, 1, 2, 5, 7, 8, 9])
def test_subpixel_form_equals_the_transposed_convolution(dim, keep):
    from lesscli.models.subpixel import subpixel_conv_t, subpixel_weights

    gen = torch.Generator().manual_seed(dim)
    conv_t = getattr(torch.nn, f"ConvTranspose{dim}d")(3, 5, kernel_size=4, stride=2, padding=1)
    x = torch.randn(2, 3, *[4, 3, 5][:dim], generator=gen)
    with torch.no_grad():
        want = conv_t(x)
        got = subpixel_conv_t(x, *subpixel_weights(conv_t), keep=keep)
    rows = want.shape[2] if keep is None else min(keep, want.shape[2])
    assert got.shape == (*want.shape[:2], rows, *want.shape[3:])
    assert float((got - want[:, :, :rows]).abs().max()) <= 1e-6


@pytest.mark.parametrize("dim,patch_px,width,depth", [(2, 16, 16, 1), (3, 16, 16, 13), (3, 32, 24, 13),
                                                     (3, 32, 16, 26), (3, 64, 32, 7), (2, 64, 16, 1),
                                                     (3, 64, 16, 64), (2, 8, 16, 1), (3, 8, 16, 5)])
def test_evaluation_decodes_like_training(dim, patch_px, width, depth):
    """Eval mode runs every layer in sub-pixel form and crops columns early; same patches as training
    (patch_px 8: the first layer is the last)."""
    dec = PatchDecoder(d_z=6, n_classes=4, dim=dim, patch_px=patch_px, depth_px=depth, width=width)
    z = torch.randn(2, 3, 6, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        trained = dec.train().patches(z)
        evaluated = dec.eval().patches(z)
    assert evaluated.shape == trained.shape == (2, 3, 4, depth, patch_px, patch_px)
    assert float((evaluated - trained).abs().max()) <= 1e-5
    for mode in (dec.eval(), dec.train()):                   # the stream canvas's layout: classes innermost
        with torch.no_grad():
            last = mode.patches(z, channels_last=True)
        assert last.stride(2) == 1 and last.stride(-1) == 4 and torch.equal(last, mode.patches(z))


def test_patch_decoder_needs_one_upsampling_layer():
    with pytest.raises(ValueError, match="k >= 1"):
        PatchDecoder(d_z=6, n_classes=4, dim=2, patch_px=4)


def test_subpixel_form_refuses_other_transposed_convolutions():
    from lesscli.models.subpixel import subpixel_weights

    with pytest.raises(ValueError, match="kernel 4, stride 2, padding 1"):
        subpixel_weights(torch.nn.ConvTranspose2d(3, 5, kernel_size=3, stride=2, padding=1))


def test_neighbour_context_reads_only_the_particles_within_its_reach():
    """context=3: a particle's decoder input changes with its 8 grid neighbours' states and with
    whether they saw anything, never with a particle two spacings away; context=0 reads itself only."""
    torch.manual_seed(0)
    n, d = 5, 6
    xy = torch.stack(torch.meshgrid(torch.arange(n) * 6.0, torch.arange(n) * 6.0, indexing="xy"),
                     -1).reshape(-1, 2)
    z, seen = torch.randn(1, n * n, d), torch.ones(1, n * n, dtype=torch.bool)
    dec = PatchDecoder(d_z=d, dim=2, patch_px=8, width=8, context=3).eval()
    base = dec.with_context(z, seen)
    assert base.shape == (1, n * n, d + dec.neighbours.out_channels)
    centre = 2 * n + 2
    for other, near in [(2 * n + 3, True), (3 * n + 3, True), (2 * n + 4, False), (0, False)]:
        moved, unseen = z.clone(), seen.clone()
        moved[0, other] += 1.0
        unseen[0, other] = False
        for out in (dec.with_context(moved, seen), dec.with_context(z, unseen)):
            assert torch.equal(out[0, centre, :d], z[0, centre])
            assert (out[0, centre] != base[0, centre]).any() == near, other
    plain = PatchDecoder(d_z=d, dim=2, patch_px=8, width=8)
    assert plain.with_context(z, seen) is z
    assert torch.isfinite(dec(_states(z, xy, seen), _grid((1, 40, 40)))).all()


@pytest.mark.parametrize("context", [2, -1])
def test_neighbour_context_must_be_odd(context):
    with pytest.raises(ValueError, match="context must be 0 or odd"):
        PatchDecoder(d_z=4, dim=2, patch_px=8, width=8, context=context)


def test_neighbour_context_needs_a_square_grid():
    dec = PatchDecoder(d_z=4, dim=2, patch_px=8, width=8, context=3)
    with pytest.raises(ValueError, match="square particle grid"):
        dec.with_context(torch.zeros(1, 6, 4), torch.ones(1, 6, dtype=torch.bool))


def test_global_decoder_norm_ignores_a_common_offset_and_scale():
    """The input norm: a state shifted and scaled as a whole (the map's evidence is never negative) decodes
    as it was; without the norm the same shift changes every logit."""
    gen = torch.Generator().manual_seed(0)
    z = torch.randn(3, 1, 96, generator=gen)
    shifted = 4.0 * z + 3.0
    for norm in (True, False):
        torch.manual_seed(1)
        dec = GlobalDecoder(d_z=96, n_classes=4, dim=2, shape=(1, 16, 16), width=8, input_norm=norm).eval()
        with torch.no_grad():
            a, b = dec(_states(z, torch.zeros(1, 2)), _grid((1, 16, 16))), \
                dec(_states(shifted, torch.zeros(1, 2)), _grid((1, 16, 16)))
        assert torch.isfinite(a).all() and torch.isfinite(b).all()
        assert (float((a - b).abs().max()) <= 1e-4) == norm


def test_global_decoder_fits_get_the_norm_and_old_checkpoints_load_without_it():
    from lesscli.models.registry import build_decoder
    from lesscli.train.image_fit import ImageFitConfig, decoder_settings

    cfg = ImageFitConfig()
    cfg.image.dim = 3
    settings = decoder_settings(cfg, "global-taxel", 24, _grid((8, 16, 16)))
    assert settings["name"] == "global" and settings["input_norm"] is True
    fitted = build_decoder(settings, seed=0)
    assert {"norm.weight", "norm.bias"} <= set(fitted.state_dict())
    old = {k: v for k, v in settings.items() if k != "input_norm"}   # a checkpoint from before the norm
    before = build_decoder(old, seed=0)
    assert not any(k.startswith("norm.") for k in before.state_dict())
    before.load_state_dict({k: v for k, v in fitted.state_dict().items() if not k.startswith("norm.")})
