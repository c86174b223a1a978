"""Particle gather, LESS/GLOBAL encoders, force decoder and SSL loss."""

from __future__ import annotations

import math

import pytest
import torch

from lesscli.errors import LessError
from lesscli.models.encoders import GlobalEncoder, ParticleEncoder
from lesscli.models.force_decoder import ForceDecoder
from lesscli.models.particles import gather_receptive_field, particle_grid
from lesscli.models.registry import ENCODERS, build_encoder, lookup
from lesscli.models.ssl_loss import ForcePredictor, sample_slots
from lesscli.types import Batch

torch.set_num_threads(1)
QUANTUM_MM = 0.25          # positions on this lattice keep float32 sums and squares exact


def make_batch(gen: torch.Generator, b: int = 2, length: int = 30, f: int = 6, span_mm: float = 20.0,
               dtype=torch.float32) -> Batch:
    """Random batch with x-y on a 0.25 mm lattice in [-span, span] and ragged valid prefixes."""
    pose = torch.zeros(b, length, 6, dtype=dtype)
    pose[..., :2] = torch.round((torch.rand(b, length, 2, generator=gen) * 2 - 1)
                                * span_mm / QUANTUM_MM) * QUANTUM_MM
    pose[..., 2] = -torch.rand(b, length, generator=gen, dtype=dtype) * 3
    pose[..., 5] = torch.rand(b, length, generator=gen, dtype=dtype)
    force = torch.randn(b, length, f, generator=gen, dtype=dtype)
    lengths = torch.randint(1, length + 1, (b,), generator=gen)
    lengths[0] = length
    valid = torch.arange(length)[None] < lengths[:, None]
    return Batch(pose=pose, force=force, valid=valid, scan_index=torch.arange(b))


def reference_gather(xy, valid, particles, radius, cap):
    """Slow reference: per (b, p) the list of in-field valid step indices in time order (first cap)."""
    out = []
    for b in range(xy.shape[0]):
        rows = []
        for p in range(particles.shape[0]):
            steps = [l for l in range(xy.shape[1]) if bool(valid[b, l])
                     and float(xy[b, l, 0] - particles[p, 0]) ** 2 + float(xy[b, l, 1] - particles[p, 1]) ** 2
                     < radius ** 2]
            rows.append(steps if cap is None else steps[:cap])
        out.append(rows)
    return out


@pytest.mark.parametrize("radius,cap,seed", [(5.0, None, 0), (7.5, 3, 1), (10.0, 1, 2), (2.0, None, 3),
                                             (math.inf, 4, 4)])
def test_gather_matches_slow_reference(radius, cap, seed):
    gen = torch.Generator().manual_seed(seed)
    batch = make_batch(gen, b=3, length=40)
    particles = particle_grid(30.0, 5.0)
    # put some steps exactly on a receptive-field boundary: strict '<' excludes them
    if math.isfinite(radius):
        batch.pose[0, :3, 0] = particles[7, 0] + radius
        batch.pose[0, :3, 1] = particles[7, 1]
    g = gather_receptive_field(batch.pose[..., :2], batch.valid, particles, radius, cap)
    ref = reference_gather(batch.pose[..., :2], batch.valid, particles, radius, cap)
    for b in range(3):
        for p in range(particles.shape[0]):
            n = int(g.count[b, p])
            assert g.index[b, p, :n].tolist() == ref[b][p]
            assert g.mask[b, p].tolist() == [i < n for i in range(g.index.shape[-1])]
            full = reference_gather(batch.pose[..., :2], batch.valid, particles[p:p + 1], radius, None)[b][0]
            assert int(g.overflow[b, p]) == len(full) - n
            if n:   # padding repeats the last real step
                assert set(g.index[b, p, n:].tolist()) <= {ref[b][p][-1]}


def test_particle_grid_is_odd_symmetric_and_grows_by_containment():
    small = particle_grid(60.0, 6.0)
    assert small.shape == (121, 2)
    assert torch.equal(small.min(0).values, torch.tensor([-30.0, -30.0]))
    big = particle_grid(120.0, 6.0)
    assert big.shape == (441, 2)
    assert {tuple(r) for r in small.tolist()} <= {tuple(r) for r in big.tolist()}
    shifted = particle_grid(12.0, 6.0, (1.5, -2.0))
    assert torch.equal(shifted.mean(0), torch.tensor([1.5, -2.0]))


def tiny_encoder(cls=ParticleEncoder, **kw) -> torch.nn.Module:
    torch.manual_seed(0)
    args = {"force_dim": 6, "dim": 8, "n_freq": 3}
    if cls is ParticleEncoder:
        args.update(spacing_mm=5.0, grid_extent_mm=20.0, receptive_field_mm=6.0)
    args.update(kw)
    return cls(**args).eval()


def test_states_are_zero_exactly_where_unseen_and_shapes_match():
    enc = tiny_encoder()
    batch = make_batch(torch.Generator().manual_seed(5))
    states = enc(batch)
    assert states.z.shape == (2, 25, 8) and states.xy_mm.shape == (25, 2)
    g = gather_receptive_field(batch.pose[..., :2], batch.valid, enc.xy_mm, 6.0)
    assert torch.equal(states.seen, g.count > 0)
    assert torch.all(states.z[~states.seen] == 0)
    assert torch.all(states.z[states.seen].abs().sum(-1) > 0)


def test_state_equals_masked_step_by_step_gru():
    """Reading at the last valid step equals updating only on real steps."""
    enc = tiny_encoder()
    batch = make_batch(torch.Generator().manual_seed(6))
    states = enc(batch)
    g = gather_receptive_field(batch.pose[..., :2], batch.valid, enc.xy_mm, 6.0)
    cell = torch.nn.GRUCell(8, 8)
    cell.weight_ih.data, cell.weight_hh.data = enc.gru.weight_ih_l0.data, enc.gru.weight_hh_l0.data
    cell.bias_ih.data, cell.bias_hh.data = enc.gru.bias_ih_l0.data, enc.gru.bias_hh_l0.data
    for b, p in [(0, 12), (1, 6), (0, 0)]:
        h = torch.zeros(1, 8)
        for c in range(g.index.shape[-1]):
            step = int(g.index[b, p, c])
            pose = batch.pose[b, step].clone()
            pose[:2] -= enc.xy_mm[p]
            new = cell(enc.fle(pose[None], batch.force[b, step][None]), h)
            h = torch.where(g.mask[b, p, c], new, h)
        torch.testing.assert_close(states.z[b, p], h[0], atol=1e-5, rtol=1e-5)


def _row(seq, p):
    """Row of particle p in a single-scan ParticleSequence."""
    return int((seq.particle_index == p).nonzero())


def test_locality_outside_touches_do_not_change_a_particle():
    """Moving or adding out-of-field touches leaves the particle's state unchanged (to float rounding: the
    other particles' step counts set the matrix sizes) and its gathered inputs bit-identical."""
    enc = tiny_encoder()
    gen = torch.Generator().manual_seed(7)
    batch = make_batch(gen, b=1, length=40)
    p = 12                                                        # the centre particle at (0, 0)
    before = enc.encode_sequence(batch)
    pose, force = batch.pose.clone(), batch.force.clone()
    outside = pose[0, :, :2].norm(dim=-1) >= 6.0
    pose[0, outside, 0] = torch.where(pose[0, outside, 0] >= 0, 9.5, -9.75)
    force[0, outside] = torch.randn(int(outside.sum()), 6, generator=gen)
    moved = Batch(pose, force, batch.valid, batch.scan_index)
    assert outside.any() and not torch.allclose(enc(moved).z[0, 13], enc(batch).z[0, 13], atol=1e-3)
    torch.testing.assert_close(enc(moved).z[0, p], enc(batch).z[0, p], atol=1e-6, rtol=0)
    extra_pose = torch.zeros(1, 15, 6)
    extra_pose[0, :, 0] = 8.0 + torch.arange(15) * 0.25
    extra_pose[0, :, 2] = -1.0
    added = Batch(torch.cat([pose[:, :10], extra_pose, pose[:, 10:]], 1),
                  torch.cat([force[:, :10], torch.randn(1, 15, 6, generator=gen), force[:, 10:]], 1),
                  torch.ones(1, 55, dtype=torch.bool), batch.scan_index)
    after = enc.encode_sequence(added)
    r1, r2 = _row(before, p), _row(after, p)
    n = int(before.count[r1])
    assert n > 0 and int(after.count[r2]) == n and after.z.shape[1] > before.z.shape[1]
    assert torch.equal(before.pose[r1, :n], after.pose[r2, :n])
    assert torch.equal(before.force[r1, :n], after.force[r2, :n])
    torch.testing.assert_close(enc(added).z[0, p], enc(batch).z[0, p], atol=1e-6, rtol=0)
    assert not torch.allclose(enc(added).z[0, 13], enc(moved).z[0, 13], atol=1e-3)   # its neighbour saw them


def test_centring_shift_of_scene_and_particles_leaves_states_unchanged():
    enc = tiny_encoder()
    batch = make_batch(torch.Generator().manual_seed(8))
    offset = (15.0, -10.0)
    shifted_pose = batch.pose.clone()
    shifted_pose[..., 0] += offset[0]
    shifted_pose[..., 1] += offset[1]
    shifted = Batch(shifted_pose, batch.force, batch.valid, batch.scan_index)
    moved_enc = enc.with_grid(20.0, center_xy_mm=offset)
    a, b = enc(batch), moved_enc(shifted)
    assert torch.equal(a.seen, b.seen)
    assert torch.equal(a.z, b.z)
    assert torch.equal(b.xy_mm, a.xy_mm + torch.tensor(offset))


def test_with_grid_keeps_weights_and_spacing_and_the_inner_particles():
    enc = tiny_encoder()
    big = enc.with_grid(40.0)
    assert big.n_particles == 81 and big.settings["spacing_mm"] == 5.0
    batch = make_batch(torch.Generator().manual_seed(9), span_mm=10.0)
    small_states, big_states = enc(batch), big(batch)
    rows = [i for i, xy in enumerate(big.xy_mm.tolist()) if max(abs(v) for v in xy) <= 10.0]
    torch.testing.assert_close(big_states.z[:, rows], small_states.z, atol=1e-6, rtol=0)


def test_global_is_one_unfiltered_uncentred_state():
    enc = tiny_encoder(GlobalEncoder)
    batch = make_batch(torch.Generator().manual_seed(10), span_mm=40.0)
    states = enc(batch)
    assert states.z.shape == (2, 1, 8) and torch.equal(states.xy_mm, torch.zeros(1, 2))
    assert states.seen.all()
    ref = tiny_encoder(ParticleEncoder, grid_extent_mm=0.0, receptive_field_mm=1e6)
    ref.load_state_dict(enc.state_dict())
    torch.testing.assert_close(ref(batch).z, states.z)
    assert enc.with_grid(200.0).n_particles == 1


def finite_loss_and_grads(model, batch):
    model.zero_grad()
    loss = model(batch, torch.Generator().manual_seed(0))
    loss.backward()
    grads = [p.grad for p in model.parameters()]
    return bool(torch.isfinite(loss)), all(g is not None and bool(torch.isfinite(g).all())
                                           for g in grads), loss


@pytest.mark.parametrize("case", ["all_outside", "single_step", "some_empty", "all_padding_but_one"])
def test_degenerate_batches_give_finite_loss_and_gradients(case):
    model = ForcePredictor(tiny_encoder().train(), ForceDecoder(6, 8, 3))
    batch = make_batch(torch.Generator().manual_seed(11), length=12)
    if case == "all_outside":
        batch.pose[..., 0] += 500.0
    elif case == "single_step":
        batch = Batch(batch.pose[:, :1], batch.force[:, :1], torch.ones(2, 1, dtype=torch.bool),
                      batch.scan_index)
    elif case == "all_padding_but_one":
        batch.valid[:] = False
        batch.valid[0, 0] = True
    loss_ok, grads_ok, loss = finite_loss_and_grads(model, batch)
    assert loss_ok and grads_ok
    if case == "all_outside":
        assert float(loss.detach()) == 0.0
    else:
        assert float(loss.detach()) > 0.0


def test_sample_slots_without_replacement_from_real_slots_only():
    mask = torch.arange(20)[None] < torch.tensor([[0], [1], [5], [20]])
    index, ok = sample_slots(mask, 8, torch.Generator().manual_seed(0))
    assert index.shape == (4, 8)
    assert ok.sum(1).tolist() == [0, 1, 5, 8]
    for r, n in enumerate([0, 1, 5, 20]):
        chosen = index[r][ok[r]].tolist()
        assert len(set(chosen)) == len(chosen) and all(c < n for c in chosen)
    assert sorted(index[2][ok[2]].tolist()) == [0, 1, 2, 3, 4]


def test_baseline_loss_is_mean_square_of_queried_forces():
    model = ForcePredictor(tiny_encoder(), ForceDecoder(6, 8, 3), k_input=50, k_query=50)
    batch = make_batch(torch.Generator().manual_seed(12))
    seq = model.encoder.encode_sequence(batch)
    per_particle = [(seq.force[r, : int(seq.count[r])] ** 2).mean() for r in range(seq.z.shape[0])]
    expected = torch.stack(per_particle).mean()
    torch.testing.assert_close(model(batch, torch.Generator().manual_seed(0), baseline=True), expected)


def test_gradcheck_tiny_model_float64():
    torch.manual_seed(0)
    enc = ParticleEncoder(force_dim=3, dim=3, spacing_mm=5.0, grid_extent_mm=10.0, receptive_field_mm=6.0,
                          n_freq=1).double()
    model = ForcePredictor(enc, ForceDecoder(3, 3, 1).double(), k_input=3, k_query=3)
    batch = make_batch(torch.Generator().manual_seed(13), b=1, length=6, f=3, span_mm=8.0,
                       dtype=torch.float64)
    names = [n for n, _ in model.named_parameters()]
    params = tuple(p.detach().clone().requires_grad_(True) for p in model.parameters())
    force = batch.force.clone().requires_grad_(True)

    def loss_of(force_in, *values):
        b = Batch(batch.pose, force_in, batch.valid, batch.scan_index)
        state = dict(zip(names, values))
        return torch.func.functional_call(model, state, (b, torch.Generator().manual_seed(1)))

    assert torch.autograd.gradcheck(loss_of, (force, *params), eps=1e-6, atol=1e-5)


def test_registry_lookup_and_rebuild():
    assert lookup(ENCODERS, "less", "encoder") is ParticleEncoder
    with pytest.raises(LessError, match="did you mean 'global'"):
        lookup(ENCODERS, "globl", "encoder")
    enc = tiny_encoder()
    again = build_encoder(enc.config())
    assert again.config() == enc.config() and torch.equal(again.xy_mm, enc.xy_mm)


def test_exact_particle_count_per_axis_is_part_of_the_config():
    """The paper's 18 x 18 grid (an even count, which an extent cannot give) survives a config round
    trip; growing the grid goes back to the extent rule."""
    from lesscli.models.encoders import ParticleEncoder
    from lesscli.models.registry import build_encoder

    enc = ParticleEncoder(90, 8, spacing_mm=3.3, n_freq=2, particles_per_axis=18)
    xy = enc.xy_mm
    assert xy.shape == (324, 2) and torch.allclose(xy.mean(0), torch.zeros(2), atol=1e-5)
    assert float(xy[:, 0].max()) == pytest.approx(8.5 * 3.3)
    again = build_encoder(enc.config())
    torch.testing.assert_close(again.xy_mm, xy, atol=0, rtol=0)
    assert enc.with_grid(30.0).n_particles == 9 * 9                      # 2 floor(30 / 6.6) + 1 per axis
