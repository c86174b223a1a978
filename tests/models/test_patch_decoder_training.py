"""The patch decoder's training path: only seen particles decoded, transposed convolutions computed in
sub-pixel form with their own backward; same logits and parameter gradients as decoding every patch
with the plain modules and masking (the previous training path), which is run in float64 as the
reference so that only the float32 rounding of the path under test counts."""

import copy
from types import SimpleNamespace

import pytest
import torch

from lesscli.models.patch_decoder import BASE_PX, PatchDecoder, place_patches, upsampling_stack
from lesscli.models.subpixel import run_train
from lesscli.types import ImageGrid

SPACING = (1.8, 0.9548, 0.9548)
RTOL = 1e-5                      # float32 rounding, relative to the largest value of each tensor


def _grid(shape, spacing=SPACING):
    d, h, w = shape
    return ImageGrid(shape, (-(d - 1) * spacing[0], -(h - 1) / 2 * spacing[1], -(w - 1) / 2 * spacing[2]),
                     spacing)


def _reference(dec: PatchDecoder, states, grid: ImageGrid) -> torch.Tensor:
    """The training forward as it was: every patch through the plain modules, placement masks the unseen."""
    z = dec.with_context(states.z, states.seen)
    b, p, _ = z.shape
    h = dec.inp(z.reshape(b * p, -1))
    h = h.view(b * p, dec.width, *([dec.base_depth] if dec.dim == 3 else []), BASE_PX, BASE_PX)
    out = dec.up(h)
    out = out[:, :, :dec.depth_px] if dec.dim == 3 else out[:, :, None]
    patches = out.reshape(b, p, *out.shape[1:])
    return place_patches(patches, states.xy_mm, grid, dec.patch_spacing_mm, states.seen, dec.stitch)


def _step(dec: PatchDecoder, forward, states, grid: ImageGrid, readout: torch.Tensor):
    """(logits, {name: gradient or None}) of a fixed random read-out of the logits."""
    dec.zero_grad(set_to_none=True)
    logits = forward(states, grid)
    (logits * readout).sum().backward()
    return logits.detach(), {name: p.grad for name, p in dec.named_parameters()}


def _close(got: torch.Tensor, want: torch.Tensor) -> bool:
    return float((got.double() - want).abs().max()) <= RTOL * float(want.abs().max())


def _float64(dec: PatchDecoder, states, readout: torch.Tensor):
    return (copy.deepcopy(dec).double(),
            SimpleNamespace(z=states.z.double(), xy_mm=states.xy_mm, seen=states.seen), readout.double())


@pytest.mark.parametrize("dim,patch_px,depth", [(2, 16, 1), (3, 16, 13), (3, 8, 5), (3, 32, 26)])
@pytest.mark.parametrize("stitch", ["sum", "mean"])
@pytest.mark.parametrize("context", [0, 3])
@pytest.mark.parametrize("seen_share", [0.7, 1.0, 0.0])
def test_training_step_equals_decoding_every_patch(dim, patch_px, depth, stitch, context, seen_share):
    gen = torch.Generator().manual_seed(dim * 100 + patch_px + context)
    torch.manual_seed(3)
    dec = PatchDecoder(d_z=6, n_classes=4, dim=dim, patch_px=patch_px, depth_px=depth,
                       patch_spacing_mm=SPACING, width=16, stitch=stitch, context=context).train()
    n = 4                                                 # a 4 x 4 particle grid, 9 mm apart
    xy = torch.stack(torch.meshgrid(torch.arange(n) * 9.0 - 13.5, torch.arange(n) * 9.0 - 13.5,
                                    indexing="xy"), -1).reshape(-1, 2)
    z = torch.randn(3, n * n, 6, generator=gen)
    seen = torch.rand(3, n * n, generator=gen) < seen_share
    seen[1, :5] = seen_share > 0.0                        # a particle seen in one scan only
    states = SimpleNamespace(z=z, xy_mm=xy, seen=seen)
    grid = _grid((depth, 48, 48))
    readout = torch.randn(3, 4, depth, 48, 48, generator=gen)
    ref, ref_states, ref_readout = _float64(dec, states, readout)
    want, want_grads = _step(ref, lambda s, g: _reference(ref, s, g), ref_states, grid, ref_readout)
    got, got_grads = _step(dec, dec, states, grid, readout)
    assert got.shape == want.shape and torch.isfinite(got).all()
    if seen_share == 0.0:
        assert torch.equal(got, torch.zeros_like(got))
        for name, grad in got_grads.items():
            assert grad is None or (torch.isfinite(grad).all()
                                    and torch.equal(grad, torch.zeros_like(grad))), name
        return
    assert _close(got, want)
    for name, grad in got_grads.items():
        assert grad is not None and _close(grad, want_grads[name]), name


def test_training_step_resamples_patches_onto_another_spacing():
    """On a grid with another spacing the zero patches of unseen particles are resampled too; same result."""
    gen = torch.Generator().manual_seed(5)
    dec = PatchDecoder(d_z=6, n_classes=3, dim=3, patch_px=16, depth_px=6, patch_spacing_mm=SPACING,
                       width=8).train()
    xy = torch.tensor([[0.0, 0.0], [5.0, -3.0], [-7.0, 4.0]])
    states = SimpleNamespace(z=torch.randn(2, 3, 6, generator=gen), xy_mm=xy,
                             seen=torch.tensor([[True, False, True], [False, False, True]]))
    grid = _grid((6, 50, 50), (SPACING[0], 0.7, 0.7))
    readout = torch.randn(2, 3, 6, 50, 50, generator=gen)
    ref, ref_states, ref_readout = _float64(dec, states, readout)
    want, want_grads = _step(ref, lambda s, g: _reference(ref, s, g), ref_states, grid, ref_readout)
    got, got_grads = _step(dec, dec, states, grid, readout)
    assert _close(got, want)
    assert all(_close(got_grads[name], want_grads[name]) for name in want_grads)


@pytest.mark.parametrize("dim,n_up,keep", [(2, 1, None), (2, 3, None), (3, 1, 5), (3, 2, 13), (3, 2, 16),
                                           (3, 3, 26), (3, 4, 7), (3, 2, 1)])
def test_run_train_equals_the_plain_stack(dim, n_up, keep):
    """Values, input and parameter gradients of ``stack(x)[:, :, :keep]`` (float64 reference), in
    channels-last memory."""
    gen = torch.Generator().manual_seed(n_up)
    torch.manual_seed(n_up)
    stack = upsampling_stack(dim, 16, 4, [(2,) * dim] * n_up)
    x = torch.randn(5, 16, *[2 if dim == 3 else BASE_PX, BASE_PX, BASE_PX][3 - dim:], generator=gen)
    results = []
    for net, run, dtype in ((copy.deepcopy(stack).double(), lambda m, v: m(v)[:, :, :keep], torch.float64),
                            (stack, lambda m, v: run_train(m, v, keep), torch.float32)):
        leaf = x.to(dtype).requires_grad_(True)
        out = run(net, leaf)
        (out * torch.randn(out.shape, generator=torch.Generator().manual_seed(9)).to(dtype)).sum().backward()
        results.append([out.detach(), leaf.grad, *(p.grad for p in net.parameters())])
    want, got = results
    assert got[0].shape == want[0].shape
    assert all(_close(g, w) for g, w in zip(got, want))
    assert got[0].stride(1) == 1                          # classes innermost


def test_training_keeps_parameters_and_checkpoints_as_they_were():
    """Parameters, gradients and state-dict tensors stay in plain memory, so checkpoints load in both ways."""
    dec = PatchDecoder(d_z=6, n_classes=4, dim=3, patch_px=16, depth_px=13, width=16).train()
    keys = list(dec.state_dict())
    states = SimpleNamespace(z=torch.randn(2, 3, 6),
                             xy_mm=torch.tensor([[0.0, 0.0], [4.0, 1.0], [-3.0, 2.0]]),
                             seen=torch.tensor([[True, False, True], [True, True, False]]))
    dec(states, _grid((13, 40, 40))).sum().backward()
    torch.optim.Adam(dec.parameters(), lr=1e-2).step()
    assert list(dec.state_dict()) == keys
    assert all(p.is_contiguous() and p.grad.is_contiguous() for p in dec.parameters())
    assert all(t.is_contiguous() for t in dec.state_dict().values())
    fresh = PatchDecoder(d_z=6, n_classes=4, dim=3, patch_px=16, depth_px=13, width=16)
    fresh.load_state_dict(dec.state_dict())
    assert all(torch.equal(a, b) for a, b in zip(fresh.state_dict().values(), dec.state_dict().values()))
