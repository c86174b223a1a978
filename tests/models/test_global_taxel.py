"""``global-taxel``: less-taxel's per-step features feeding one state per scan (the fair global partner)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from test_taxel import LAYOUT, _batch, _inputs, _stiff_spot_touches

from lesscli.models.global_taxel import GlobalTaxelEncoder
from lesscli.models.registry import ENCODERS, build_encoder
from lesscli.models.taxel import TaxelParticleEncoder

torch.set_num_threads(1)


def _global(**kw) -> GlobalTaxelEncoder:
    torch.manual_seed(0)
    return GlobalTaxelEncoder(90, LAYOUT, dim=8, n_freq=3, **kw)


def test_one_state_and_a_map_over_the_whole_insert():
    enc = _global()                                           # 60 mm at 2.5 mm: 24 x 24 cells
    assert enc.n_particles == 1 and enc.cells == math.ceil(60 / 2.5) ** 2 and enc.dim == 8 + 3 * enc.cells
    assert ENCODERS["global-taxel"] is GlobalTaxelEncoder


@pytest.mark.parametrize("spot", [(16.25, -8.75), (-21.25, 3.75)])
def test_map_peaks_where_the_stiff_spot_was_felt_anywhere_on_the_insert(spot):
    """Touches around a spot far from the centre (in phantom coordinates, not centred on a particle)."""
    enc = _global().eval()
    pose, force = _stiff_spot_touches((0.0, 0.0))
    pose[:, :2] += torch.tensor(spot, dtype=pose.dtype)      # the same touches moved over the spot
    with torch.no_grad():
        z = enc(_batch(pose, force)).z[0, 0]
    g, m, side = enc.gru_dim, enc.cells, math.isqrt(enc.cells)
    evidence = z[g + 2 * m:]
    covered = evidence > evidence.max() * 0.2
    axis = (np.arange(side) - (side - 1) / 2) * 2.5
    best = int(torch.where(covered, z[g + m:g + 2 * m], torch.full_like(evidence, -1e9)).argmax())
    assert (axis[best % side], axis[best // side]) == pytest.approx(spot)


def test_its_map_equals_a_less_taxel_particle_map_on_the_same_cells():
    """A map of 7 x 7 cells (17.5 mm) holds what the centre particle of less-taxel holds when that particle's
    field takes every step: the same features, kept the same way, only not local."""
    gen = torch.Generator().manual_seed(7)
    pose, force = _inputs(gen, n=30)
    glob = _global(grid_extent_mm=17.5).eval()
    local = TaxelParticleEncoder(90, LAYOUT, dim=8, n_freq=3, spacing_mm=8.0, grid_extent_mm=0.0,
                                 receptive_field_mm=100.0, particles_per_axis=1).eval()
    with torch.no_grad():
        a, b = glob(_batch(pose, force)).z[0, 0], local(_batch(pose, force)).z[0, 0]
    assert glob.cells == local.cells == 49
    torch.testing.assert_close(a[8:], b[8:], atol=1e-6, rtol=0)


def test_training_evaluation_and_streaming_steps_agree():
    enc = _global(grid_extent_mm=30.0)
    pose, force = _inputs(torch.Generator().manual_seed(5), n=25)
    pose[:, :2] *= 3
    batch = _batch(pose, force)
    with torch.no_grad():
        packed = enc.train().encode_sequence(batch).final_states()
        fixed = enc.eval()(batch)
        h = torch.zeros(1, enc.dim)
        for i in range(pose.shape[0]):                       # one step at a time, uncentred, every step
            h = enc.gru_step(enc.fle(pose[i:i + 1], force[i:i + 1]), h)
    torch.testing.assert_close(packed.z, fixed.z, atol=1e-5, rtol=0)
    torch.testing.assert_close(fixed.z[0], h, atol=1e-5, rtol=0)


def test_registry_round_trip_and_a_larger_grid_is_itself():
    enc = _global(grid_extent_mm=40.0, map_contrast="plane").eval()
    again = build_encoder(enc.config())
    again.load_state_dict(enc.state_dict())
    pose, force = _inputs(torch.Generator().manual_seed(3), n=20)
    with torch.no_grad():
        a, b, grown = enc(_batch(pose, force)), again.eval()(_batch(pose, force)), enc.with_grid(120.0)
        torch.testing.assert_close(a.z, b.z, atol=0, rtol=0)
        torch.testing.assert_close(grown(_batch(pose, force)).z, a.z, atol=0, rtol=0)
    assert again.settings == enc.settings and again.cells == 16 ** 2


@pytest.mark.parametrize("extent, pitch", [(0.0, 2.5), (60.0, 0.0), (-1.0, 2.5)])
def test_map_size_must_be_positive(extent, pitch):
    with pytest.raises(ValueError, match="global-taxel"):
        GlobalTaxelEncoder(90, LAYOUT, grid_extent_mm=extent, map_pitch_mm=pitch)


def test_cli_global_taxel_pretrain_fit_predict_round_trip(run_less, tmp_path):
    """Through the CLI: pretrain --model global-taxel, image fit (the global decoder), predict."""
    from imaging_factory import learnable_scanset

    from lesscli.io.predictions import load_predictions
    from lesscli.io.scans import save_scans

    save_scans(str(tmp_path / "tr.npz"), learnable_scanset(3, seed=1))
    save_scans(str(tmp_path / "va.npz"), learnable_scanset(2, seed=2))
    env = {"OMP_NUM_THREADS": "1"}
    run_less("pretrain", "tr.npz", "-o", "rep.pt", "--model", "global-taxel", "--epochs", "1", "--dim", "8",
             "--set", "n_freq=2", "--set", "map_pitch_mm=5", "--device", "cpu", check=True, env=env)
    fit = json.loads(run_less("image", "fit", "tr.npz", "--val", "va.npz", "--rep", "rep.pt", "-o", "img.pt",
                              "--epochs", "2", "--set", "image.width=8", "--device", "cpu", "--format",
                              "jsonl", check=True, env=env).stdout)
    assert fit["encoder"] == "global-taxel" and fit["decoder"] == "global"
    run_less("image", "predict", "img.pt", "va.npz", "-o", "pred.npz", "--device", "cpu", check=True, env=env)
    preds = load_predictions(str(tmp_path / "pred.npz"))
    assert preds.meta["model"] == "global-taxel"
    assert all(np.isfinite(p.probs.astype(np.float32)).all() for p in preds.scans)
