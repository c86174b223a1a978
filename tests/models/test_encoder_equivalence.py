"""The fast LESS paths (ragged GRU, factored force decoder) against straightforward
references of the same maths: the library's packed GRU over the FLE of every gathered slot, a masked
GRU-cell update of every particle slot by slot, and the decoder's MLP over the broadcast pairs."""

from __future__ import annotations

import tomllib

import pytest
import torch
from torch.nn.utils.rnn import pack_padded_sequence, pad_packed_sequence

from lesscli.data.batching import Batch
from lesscli.models.encoders import ParticleEncoder, ParticleSequence
from lesscli.models.encoding import POSE_DIM
from lesscli.models.force_decoder import ForceDecoder
from lesscli.models.particles import gather_receptive_field
from lesscli.models.recurrence import ragged_gru
from lesscli.models.ssl_loss import ForcePredictor, ssl_loss

torch.set_num_threads(1)
TOL = 1e-5


def scans(gen: torch.Generator, b: int = 2, length: int = 120, f: int = 12) -> Batch:
    """10-step pokes at random x-y over +-15 mm, ragged valid prefixes."""
    pokes = length // 10
    pose = torch.zeros(b, pokes, 10, 6)
    pose[..., :2] = ((torch.rand(b, pokes, 1, 2, generator=gen) * 2 - 1) * 15.0).expand(-1, -1, 10, -1)
    pose[..., 2] = -torch.linspace(0, 3, 10)
    pose[..., 5] = torch.rand(b, pokes, 1, generator=gen)
    pose = pose.reshape(b, length, 6)
    valid = torch.arange(length)[None] < torch.tensor([length, length - 37])[:b, None]
    return Batch(pose, torch.randn(b, length, f, generator=gen), valid, torch.arange(b))


def model(cap: int | None = None, k: int = 5) -> ForcePredictor:
    torch.manual_seed(3)
    enc = ParticleEncoder(12, dim=24, spacing_mm=5.0, grid_extent_mm=30.0, receptive_field_mm=7.0,
                          max_steps_per_particle=cap, n_freq=4)
    return ForcePredictor(enc, ForceDecoder(12, 24, 4), k_input=k, k_query=k)


def reference_sequence(enc: ParticleEncoder, batch: Batch) -> ParticleSequence:
    """FLE of every gathered slot, the library's packed GRU, padded back (zeros past each count)."""
    xy = enc.xy_mm
    g = gather_receptive_field(batch.pose[..., :2], batch.valid, xy, enc.receptive_field_mm, enc.max_steps)
    bi, pi = g.seen.nonzero(as_tuple=True)
    index = g.index[bi, pi]
    shift = torch.zeros(pi.shape[0], 1, POSE_DIM)
    shift[:, 0, :2] = xy[pi]
    pose, force, count = (batch.pose[bi[:, None], index] - shift, batch.force[bi[:, None], index],
                          g.count[bi, pi])
    packed = pack_padded_sequence(enc.fle(pose, force), count, batch_first=True, enforce_sorted=False)
    z = pad_packed_sequence(enc.gru(packed)[0], batch_first=True, total_length=index.shape[1])[0]
    return ParticleSequence(bi, pi, z, pose, force, g.mask[bi, pi], count, tuple(g.count.shape), xy)


def reference_final_states(enc: ParticleEncoder, batch: Batch) -> torch.Tensor:
    """(B, P, d_z): every particle advanced slot by slot by the GRU cell where the slot is a real step."""
    g = gather_receptive_field(batch.pose[..., :2], batch.valid, enc.xy_mm, enc.receptive_field_mm,
                               enc.max_steps)
    b, p, c = g.index.shape
    shift = torch.zeros(p, POSE_DIM)
    shift[:, :2] = enc.xy_mm
    scan = torch.arange(b)[:, None]
    h = torch.zeros(b * p, enc.dim)
    for slot in range(c):
        step = g.index[:, :, slot]
        x = enc.fle(batch.pose[scan, step] - shift, batch.force[scan, step]).reshape(b * p, -1)
        h = torch.where(g.mask[:, :, slot].reshape(-1, 1), enc.gru_step(x, h), h)
    return h.view(b, p, enc.dim)


class ReferenceDecoder(torch.nn.Module):
    """The force decoder's MLP over every (state, query) pair, as written in its formula."""

    def __init__(self, decoder: ForceDecoder) -> None:
        super().__init__()
        self.d = decoder

    def forward(self, z, pose):
        return self.d.out_mlp(self.d.state_mlp(z)[:, :, None, :] + self.d.pose_encoding(pose)[:, None, :, :])


@pytest.mark.parametrize("cap", [None, 6])
def test_states_and_sequence_match_the_references(cap):
    net = model(cap)
    batch = scans(torch.Generator().manual_seed(0))
    with torch.no_grad():
        seq, ref = net.encoder.encode_sequence(batch), reference_sequence(net.encoder, batch)
        states = net.encoder.eval()(batch)
        slow = reference_final_states(net.encoder, batch)
    assert seq.z.shape == ref.z.shape and seq.z.shape[0] > 0 and not states.seen.all()
    assert int(seq.count.max()) > 1 and int(seq.count.min()) >= 1
    torch.testing.assert_close(seq.z, ref.z, atol=TOL, rtol=TOL)
    torch.testing.assert_close(states.z, slow, atol=TOL, rtol=TOL)
    assert torch.all(states.z[~states.seen] == 0)


@pytest.mark.parametrize("k", [3, 8])
def test_loss_and_gradients_match_the_reference(k):
    net = model(k=k)
    batch = scans(torch.Generator().manual_seed(1))
    params = list(net.parameters())
    loss = net(batch, torch.Generator().manual_seed(5))
    ref = ssl_loss(reference_sequence(net.encoder, batch), ReferenceDecoder(net.decoder),
                   torch.Generator().manual_seed(5), k, k)
    torch.testing.assert_close(loss, ref, atol=TOL, rtol=TOL)
    for fast, slow in zip(torch.autograd.grad(loss, params), torch.autograd.grad(ref, params)):
        torch.testing.assert_close(fast, slow, atol=TOL, rtol=1e-4)


def test_ragged_gru_equals_the_library_gru_in_float64_with_empty_rows():
    torch.manual_seed(0)
    gru = torch.nn.GRU(5, 7, batch_first=True).double()
    x = torch.randn(6, 8, 5, dtype=torch.float64, requires_grad=True)
    count = torch.tensor([8, 0, 3, 1, 8, 5])
    keep = count > 0
    packed = pack_padded_sequence(x[keep], count[keep], batch_first=True, enforce_sorted=False)
    ref = torch.zeros(6, 8, 7, dtype=torch.float64).index_put(
        (keep.nonzero()[:, 0],), pad_packed_sequence(gru(packed)[0], batch_first=True, total_length=8)[0])
    out = ragged_gru(x, count, gru)
    torch.testing.assert_close(out, ref, atol=1e-12, rtol=0)
    weights = torch.randn(6, 8, 7, dtype=torch.float64)
    grads = torch.autograd.grad((out * weights).sum(), [x, *gru.parameters()])
    grads_ref = torch.autograd.grad((ref * weights).sum(), [x, *gru.parameters()])
    for a, b in zip(grads, grads_ref):
        torch.testing.assert_close(a, b, atol=1e-12, rtol=0)


def test_bench_runs_the_published_sampling_and_refuses_bad_settings():
    from click.testing import CliRunner

    from lesscli.bench.train import Size, bench_config, build
    from lesscli.cli.bench_train import cli
    from lesscli.errors import LessError

    cfg = bench_config(("ssl.k_input=8", "k_query=8"))
    net = build("less", Size("tiny", 8, 3), ssl=cfg.ssl)
    assert (net.k_input, net.k_query) == (8, 8)
    with pytest.raises(LessError, match="k_input = 0 is invalid"):
        bench_config(("ssl.k_input=0",))
    result = CliRunner().invoke(cli, ["--quick", "--set", "model.dim=8"])
    assert result.exit_code == 1 and "unknown table 'model'" in str(result.exception or result.output)
    printed = CliRunner().invoke(cli, ["--quick", "--set", "ssl.k_input=8", "--print-config"])
    assert printed.exit_code == 0 and tomllib.loads(printed.output)["ssl"]["k_input"] == 8
