"""Each fast path of the decoder against its plain form on the same weights, switched off on the
instance: the same outputs and gradients to float32 rounding (``less bench imaging`` times them)."""

import copy

import pytest
import torch

from lesscli.models.encoders import ParticleEncoder
from lesscli.models.patch_decoder import PatchDecoder

RTOL = 5e-5                      # float32 rounding of sums over a batch, relative to the largest value


def _close(got: torch.Tensor, want: torch.Tensor) -> bool:
    return float((got - want).abs().max()) <= RTOL * max(float(want.abs().max()), 1.0)


def _grads(module: torch.nn.Module) -> dict:
    return {name: p.grad for name, p in module.named_parameters() if p.grad is not None}


def _plain(module: torch.nn.Module, switch: str) -> torch.nn.Module:
    other = copy.deepcopy(module)
    setattr(other, switch, False)
    return other


@pytest.mark.parametrize("dim,patch_px,depth", [(2, 16, 1), (3, 16, 13), (3, 32, 26)])
def test_subpixel_training_equals_the_modules(dim, patch_px, depth):
    torch.manual_seed(0)
    fast = PatchDecoder(d_z=6, n_classes=4, dim=dim, patch_px=patch_px, depth_px=depth, width=16).train()
    plain = _plain(fast, "subpixel_train")
    z = torch.randn(2, 5, 6, generator=torch.Generator().manual_seed(1))
    seen = torch.tensor([[True, False, True, True, False], [False, True, True, False, True]])
    out = {}
    for name, dec in (("fast", fast), ("plain", plain)):
        patches = dec.patches(z, seen=seen)
        (patches * torch.linspace(-1, 1, patches.numel()).view_as(patches)).sum().backward()
        out[name] = patches.detach(), _grads(dec)
    assert _close(out["fast"][0], out["plain"][0])
    assert out["fast"][1].keys() == out["plain"][1].keys()
    for name, grad in out["fast"][1].items():
        assert _close(grad, out["plain"][1][name]), name


@pytest.mark.parametrize("dim,patch_px,depth", [(2, 16, 1), (3, 16, 13), (3, 32, 26), (2, 8, 1)])
@pytest.mark.parametrize("channels_last", [False, True])
def test_subpixel_evaluation_equals_the_modules(dim, patch_px, depth, channels_last):
    torch.manual_seed(0)
    fast = PatchDecoder(d_z=6, n_classes=4, dim=dim, patch_px=patch_px, depth_px=depth, width=16).eval()
    plain = _plain(fast, "subpixel_eval")
    z = torch.randn(2, 3, 6, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        got, want = fast.patches(z, channels_last), plain.patches(z, channels_last)
    assert got.shape == want.shape == (2, 3, 4, depth, patch_px, patch_px) and _close(got, want)
    if channels_last:                                   # the stream canvas's layout: classes innermost
        assert got.stride(2) == want.stride(2) == 1 and got.stride(-1) == want.stride(-1) == 4


def test_subpixel_evaluation_follows_parameter_updates():
    """The sub-pixel weights are rearranged on every call: an optimiser's in-place step shows at once."""
    dec = PatchDecoder(d_z=6, n_classes=4, dim=2, patch_px=16, width=16).eval()
    z = torch.randn(1, 2, 6, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        before = dec.patches(z)
        dec.up[-1].weight.mul_(2.0)                     # in place, as an optimiser step is
        after = dec.patches(z)
        assert not torch.equal(before, after) and _close(after, _plain(dec, "subpixel_eval").patches(z))


def test_the_taxel_encoder_keeps_the_papers_fle_under_its_own_name():
    """less-taxel's FLE feeds its GRU beside the stiffness map: registered as ``paper_fle`` (its
    checkpoints' keys), with :meth:`fle` the step inputs."""
    from lesscli.models.taxel import TaxelParticleEncoder

    enc = TaxelParticleEncoder(90, torch.zeros(30, 2), dim=8)
    keys = enc.state_dict()
    assert "paper_fle.force_mlp.0.weight" in keys and not any(k.startswith("fle.") for k in keys)
    assert "fle.force_mlp.0.weight" in ParticleEncoder(90, dim=8).state_dict()
