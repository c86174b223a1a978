"""Taxel-aware LESS encoder (``less-taxel``): taxel geometry, the stiffness map, exact paths, hard cases."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from factories import random_scanset, tiny_cfg

from lesscli.data.batching import compute_norm_stats
from lesscli.errors import DataError
from lesscli.io.sensor import xela_uscu
from lesscli.models.registry import ENCODERS, build_encoder
from lesscli.models.taxel import TaxelParticleEncoder, taxel_xy
from lesscli.train.pretrain import build_model, pretrain
from lesscli.types import Batch

torch.set_num_threads(1)
LAYOUT = xela_uscu()["taxel_xy_mm"]


def independent_taxel_xy(pose: np.ndarray, layout) -> np.ndarray:
    """Taxel x-y by explicit matrices Rz(yaw) Ry(pitch) Rx(roll), written out here, not by the library."""
    out = []
    for x, y, _z, roll, pitch, yaw in pose:
        rx = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)], [0, math.sin(roll), math.cos(roll)]])
        ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0],
                       [-math.sin(pitch), 0, math.cos(pitch)]])
        rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
        r = rz @ ry @ rx
        out.append([[x + r[0, 0] * u + r[0, 1] * v, y + r[1, 0] * u + r[1, 1] * v] for u, v in layout])
    return np.array(out)


def test_taxel_positions_match_explicit_rotation_and_simulator():
    from lesscli.sim.kinematics import taxel_centres_mm

    rng = np.random.default_rng(0)
    pose = np.column_stack([rng.uniform(-20, 20, (16, 2)), rng.uniform(-5, 5, 16),
                            rng.uniform(-0.4, 0.4, (16, 2)), rng.uniform(-math.pi, math.pi, 16)])
    got = taxel_xy(torch.tensor(pose, dtype=torch.float64), torch.tensor(LAYOUT, dtype=torch.float64)).numpy()
    np.testing.assert_allclose(got, independent_taxel_xy(pose, LAYOUT), atol=1e-9)
    np.testing.assert_allclose(got, taxel_centres_mm(pose, xela_uscu())[..., :2], atol=1e-9)


def test_quarter_turn_maps_taxel_x_to_y():
    pose = torch.tensor([[1.0, 2.0, -1.0, 0.0, 0.0, math.pi / 2]], dtype=torch.float64)
    got = taxel_xy(pose, torch.tensor([[3.0, 0.0]], dtype=torch.float64))
    np.testing.assert_allclose(got.numpy(), [[[1.0, 5.0]]], atol=1e-12)


def _inputs(gen, n=5, taxels=30):
    pose = torch.zeros(n, 6)
    pose[:, :2] = torch.rand(n, 2, generator=gen) * 10 - 5
    pose[:, 2] = -torch.rand(n, generator=gen) * 3
    pose[:, 5] = torch.rand(n, generator=gen) * 1.4
    return pose, torch.rand(n, taxels * 3, generator=gen)


def _encoder(**kw) -> TaxelParticleEncoder:
    torch.manual_seed(0)
    return TaxelParticleEncoder(90, LAYOUT, dim=8, spacing_mm=8.0, grid_extent_mm=32.0, n_freq=3, **kw)


def _batch(pose, force) -> Batch:
    n = pose.shape[0]
    return Batch(pose=pose[None], force=force[None], valid=torch.ones(1, n, dtype=torch.bool),
                 scan_index=torch.zeros(1, dtype=torch.long))


def _stiff_spot_touches(spot_xy, n=12, seed=4):
    """Pokes 2 mm deep at random places and yaws; taxels within 3 mm of ``spot_xy`` press 3x harder.

    Forces are written from the taxel geometry of :func:`independent_taxel_xy`, not the encoder's.
    """
    rng = np.random.default_rng(seed)
    pose = np.zeros((n, 6))
    pose[:, :2] = rng.uniform(-4, 4, (n, 2))
    pose[:, 2] = -2.0
    pose[:, 5] = rng.uniform(0, 1.4, n)
    xy = independent_taxel_xy(pose, LAYOUT)                                        # (n, T, 2)
    near = np.linalg.norm(xy - np.asarray(spot_xy), axis=-1) < 3.0
    force = np.zeros((n, 30, 3))
    force[..., 2] = np.where(near, 3.0, 1.0)
    return torch.tensor(pose, dtype=torch.float32), torch.tensor(force.reshape(n, 90), dtype=torch.float32)


@pytest.mark.parametrize("spot", [(2.5, -2.5), (-5.0, 0.0), (0.0, 7.5)])
def test_map_peaks_where_the_taxels_felt_the_stiff_spot(spot):
    enc = _encoder().eval()
    pose, force = _stiff_spot_touches(spot)
    with torch.no_grad():
        states = enc(_batch(pose, force))
    centre = int(((states.xy_mm - 0) ** 2).sum(-1).argmin())                       # the particle at 0, 0
    z = states.z[0, centre]
    g, m = enc.gru_dim, enc.cells
    evidence = z[g + 2 * m:]
    covered = evidence > evidence.max() * 0.2
    axis = (np.arange(7) - 3) * 2.5
    for channel in (z[g:g + m], z[g + m:g + 2 * m]):            # mean log stiffness, contrast within a step
        best = int(torch.where(covered, channel, torch.full_like(channel, -1e9)).argmax())
        assert (axis[best % 7], axis[best // 7]) == pytest.approx(spot)


def test_samples_count_by_indentation():
    """Two uniform presses at the particle, 1 mm deep (force 3 per taxel) and 3 mm deep (force 14):
    every covered cell holds the indentation-weighted mean of log(f / (d + 0.5)), no within-step
    contrast, and log(1 + weight) with weight proportional to 1 + 3 mm."""
    enc = _encoder().eval()
    pose = torch.zeros(2, 6)
    pose[:, 2] = torch.tensor([-1.0, -3.0])
    force = torch.zeros(2, 30, 3)
    force[0, :, 2], force[1, :, 2] = 3.0, 14.0
    with torch.no_grad():
        states = enc(_batch(pose, force.reshape(2, 90)))
    z = states.z[0, int((states.xy_mm ** 2).sum(-1).argmin())]
    g, m = enc.gru_dim, enc.cells
    centre = m // 2
    expected = (1.0 * math.log(3.0 / 1.5) + 3.0 * math.log(14.0 / 3.5)) / 4.0
    assert float(z[g + centre]) == pytest.approx(expected, abs=1e-4)
    assert float(z[g + m:g + 2 * m].abs().max()) < 1e-5
    with torch.no_grad():                                                 # the same presses, both 1 mm deep
        shallow = pose.clone()
        shallow[:, 2] = -1.0
        once = enc(_batch(shallow, force.reshape(2, 90))).z[0, int((states.xy_mm ** 2).sum(-1).argmin())]
    weight = torch.expm1(z[g + 2 * m:]) / torch.expm1(once[g + 2 * m:])
    torch.testing.assert_close(weight, torch.full_like(weight, 2.0), atol=1e-4, rtol=0)


@pytest.mark.parametrize("contrast", ["step", "plane"])
def test_training_evaluation_and_streaming_steps_agree(contrast):
    enc = _encoder(map_contrast=contrast)
    gen = torch.Generator().manual_seed(5)
    pose, force = _inputs(gen, n=25)
    pose[:, :2] *= 3
    batch = _batch(pose, force)
    with torch.no_grad():
        packed = enc.train().encode_sequence(batch).final_states()
        fixed = enc.eval()(batch)
        h = torch.zeros(enc.n_particles, enc.dim)
        for i in range(pose.shape[0]):                          # one step at a time, as a stream does
            centred = pose[i].expand(enc.n_particles, 6).clone()
            centred[:, :2] -= enc.xy_mm
            inside = (centred[:, :2] ** 2).sum(-1) < enc.receptive_field_mm ** 2
            step = enc.gru_step(enc.fle(centred, force[i].expand(enc.n_particles, 90)), h)
            h = torch.where(inside[:, None], step, h)
    torch.testing.assert_close(packed.z, fixed.z, atol=1e-5, rtol=0)
    torch.testing.assert_close(fixed.z[0], h, atol=1e-5, rtol=0)


@pytest.mark.parametrize("contrast", ["step", "plane"])
@pytest.mark.parametrize("case",
                         ["zero_contact", "grazing", "no_force", "huge_force", "pad_above", "one_taxel"])
def test_hard_cases_stay_finite(case, contrast):
    enc = _encoder(map_contrast=contrast)
    gen = torch.Generator().manual_seed(2)
    pose, force = _inputs(gen)
    if case == "zero_contact":
        pose[:, 2] = 0.0
    elif case == "grazing":
        pose[:, 2] = -1e-4
    elif case == "no_force":
        force.zero_()
    elif case == "huge_force":
        force *= 1e6
    elif case == "one_taxel":                                           # a plane through one point
        force[:, 3:] = 0.0
    else:
        pose[:, 2] = 8.0
        force.zero_()
    pose.requires_grad_()
    states = enc.train().encode_sequence(_batch(pose, force)).final_states()
    states.z.sum().backward()
    assert torch.isfinite(states.z).all() and torch.isfinite(pose.grad).all()
    if case in ("zero_contact", "no_force", "pad_above"):            # nothing pressed: an empty map
        assert float(states.z.detach()[..., enc.gru_dim:].abs().max()) == 0.0


def _ramp_and_bump_step(bump: bool):
    """One 2 mm press whose log stiffness rises linearly across the pad (as towards an insert's centre
    from its soft edge), plus, with ``bump``, the 4 taxels nearest the pad centre 3x stiffer."""
    xy = np.asarray(LAYOUT)
    k = np.exp(0.08 * xy[:, 0] + 0.03 * xy[:, 1])
    if bump:
        k[np.argsort(np.hypot(xy[:, 0], xy[:, 1]))[:4]] *= 3.0
    force = np.zeros((1, 30, 3))
    force[0, :, 2] = k * 2.5
    pose = torch.zeros(1, 6)
    pose[0, 2] = -2.0
    return pose, torch.tensor(force.reshape(1, 90), dtype=torch.float32), k


@pytest.mark.parametrize("bump", [False, True])
def test_plane_contrast_ignores_a_ramp_and_keeps_a_bump(bump):
    pose, force, k = _ramp_and_bump_step(bump)
    taxels = torch.tensor(LAYOUT, dtype=torch.float32)
    log_k = torch.tensor(np.log(k), dtype=torch.float32)[None]
    on = torch.ones_like(log_k)
    plane = _encoder(map_contrast="plane")
    step = _encoder(map_contrast="step")
    residual = (log_k - plane._step_trend(on, log_k))[0]
    centred = (log_k - step._step_trend(on, log_k))[0]
    near = torch.tensor(np.argsort(np.hypot(*np.asarray(LAYOUT).T))[:4])
    if bump:
        assert float(residual[near].min()) > 0.5                        # the bump stands out of the plane
    else:
        assert float(residual.abs().max()) < 1e-3                       # a pure ramp leaves no contrast
    assert float(centred.abs().max()) > 0.5                             # the step mean keeps the ramp
    with torch.no_grad():                                              # and the map holds the residual
        states = plane.eval()(_batch(pose, force))
    assert torch.isfinite(states.z).all() and taxels.shape[0] == 30


def test_map_contrast_is_a_less_taxel_setting():
    from lesscli.errors import LessError
    from lesscli.train.config import PretrainConfig
    from lesscli.train.pretrain import encoder_kwargs

    cfg = PretrainConfig()
    cfg.model.name, cfg.model.map_contrast = "less-taxel", "plane"
    kwargs = encoder_kwargs(cfg, 90, LAYOUT)
    assert kwargs["map_contrast"] == "plane"
    enc = build_encoder({"name": "less-taxel", **_encoder(map_contrast="plane").config()})
    assert enc.map_contrast == "plane"
    cfg.model.name = "less"
    with pytest.raises(LessError, match="map_contrast = 'plane' applies to less-taxel only"):
        encoder_kwargs(cfg, 90)
    with pytest.raises(ValueError, match="map_contrast"):
        _encoder(map_contrast="edge")


@pytest.mark.parametrize("key, value", [("map_cells", 9), ("map_pitch_mm", 2.0)])
def test_map_size_is_a_less_taxel_setting(key, value):
    from lesscli.errors import LessError
    from lesscli.train.config import PretrainConfig
    from lesscli.train.pretrain import build_model

    cfg = PretrainConfig()
    cfg.model.name, cfg.model.dim = "less-taxel", 8
    setattr(cfg.model, key, value)
    enc = build_model(cfg, 90, LAYOUT).encoder
    assert enc.settings[key] == value
    cells = enc.settings["map_cells"]
    assert enc.dim == 8 + 3 * cells * cells and enc.axis_mm.numel() == cells
    assert float(enc.axis_mm[1] - enc.axis_mm[0]) == pytest.approx(enc.settings["map_pitch_mm"])
    again = build_encoder(enc.config())                                  # the checkpoint keeps the map size
    assert again.dim == enc.dim and again.settings[key] == value
    cfg.model.name = "less"
    with pytest.raises(LessError, match=f"model.{key} = {value!r} applies to less-taxel only"):
        build_model(cfg, 90)


def test_registry_round_trip_and_grown_grid_keep_outputs():
    enc = _encoder().eval()
    again = build_encoder(enc.config())
    again.load_state_dict(enc.state_dict())
    pose, force = _inputs(torch.Generator().manual_seed(3), n=20)
    with torch.no_grad():
        a, b = enc(_batch(pose, force)), again.eval()(_batch(pose, force))
        grown = enc.with_grid(48.0)(_batch(pose, force))
    torch.testing.assert_close(a.z, b.z, atol=0, rtol=0)
    inner = [i for i, xy in enumerate(grown.xy_mm.tolist()) if max(abs(v) for v in xy) <= 16.0]
    torch.testing.assert_close(grown.z[:, inner], a.z, atol=1e-6, rtol=0)
    assert ENCODERS["less-taxel"] is TaxelParticleEncoder and enc.dim == 8 + 3 * 49


def test_layout_must_match_force_features():
    with pytest.raises(ValueError, match="taxels"):
        TaxelParticleEncoder(60, LAYOUT, dim=8)


def test_scale_normalisation_keeps_zero_force_at_zero():
    scans = random_scanset(n_scans=2, seed=0)
    stats = compute_norm_stats(scans, "scale")
    assert stats["force_mean"] == [0.0] * 90
    for t in (0, 7):
        rms = math.sqrt(float((scans.force[:, t, 2].astype(np.float64) ** 2).mean()))
        assert stats["force_std"][3 * t:3 * t + 3] == pytest.approx([rms] * 3)


def test_pretrain_less_taxel_uses_layout_and_scale(tmp_path):
    scans = random_scanset(n_scans=3, seed=1)
    cfg = tiny_cfg(epochs=1)
    cfg.model.name = "less-taxel"
    out = str(tmp_path / "rep.pt")
    summary = pretrain(scans, None, cfg, out)
    ckpt = torch.load(out, weights_only=True)
    assert ckpt["norm_stats"]["mode"] == "scale" and ckpt["config"]["decoder"]["name"] == "mlp"
    assert ckpt["config"]["encoder"]["taxel_xy_mm"] == LAYOUT and math.isfinite(summary["best_loss"])


def test_less_taxel_without_layout_is_a_clear_error():
    cfg = tiny_cfg()
    cfg.model.name = "less-taxel"
    with pytest.raises(DataError, match="taxel layout"):
        build_model(cfg, 90, None)



def test_cli_less_taxel_pretrain_fit_predict_round_trip(run_less, tmp_path):
    """Through the CLI: pretrain --model less-taxel, image fit --val (threshold chosen and stored),
    predict."""
    from imaging_factory import learnable_scanset

    from lesscli.io.scans import save_scans

    save_scans(str(tmp_path / "tr.npz"), learnable_scanset(3, seed=1))
    save_scans(str(tmp_path / "va.npz"), learnable_scanset(2, seed=2))
    env = {"OMP_NUM_THREADS": "1"}
    run_less("pretrain", "tr.npz", "-o", "rep.pt", "--model", "less-taxel", "--epochs", "1", "--dim", "8",
             "--spacing-mm", "10", "--set", "n_freq=2", "--device", "cpu", check=True, env=env)
    fit = json.loads(run_less("image", "fit", "tr.npz", "--val", "va.npz", "--rep", "rep.pt", "-o", "img.pt",
                              "--epochs", "2", "--set", "image.patch_px=8", "--set", "image.width=8",
                              "--device", "cpu", "--format", "jsonl", check=True, env=env).stdout)
    stored = torch.load(str(tmp_path / "img.pt"), weights_only=True)["config"]
    assert stored["encoder"]["name"] == "less-taxel" and stored["image"]["threshold"] == fit["threshold"]
    assert stored["image"]["min_volume_mm3"] == fit["min_volume_mm3"]
    assert stored["image"]["smooth_mm"] == fit["smooth_mm"]
    sizing = fit["val_diameter_error_mm_by_labelling"]
    assert sizing.keys() == fit["val_f1_by_labelling"].keys() and sizing[f"{fit['smooth_mm']:g}"][
        str(fit["threshold"])][f"{fit['min_volume_mm3']:g}"] >= 0
    run_less("image", "predict", "img.pt", "va.npz", "-o", "pred.npz", "--device", "cpu", check=True, env=env)
    from lesscli.io.predictions import load_predictions

    preds = load_predictions(str(tmp_path / "pred.npz"))
    assert preds.meta["model"] == "less-taxel" and preds.meta["threshold"] == fit["threshold"]
    assert (preds.meta["min_volume_mm3"] == fit["min_volume_mm3"]
            and preds.meta["smooth_mm"] == fit["smooth_mm"])
    assert all(np.isfinite(p.probs.astype(np.float32)).all() for p in preds.scans)


@pytest.mark.parametrize("key, value, rule", [("map_cells", 0, ">= 1"), ("map_pitch_mm", 0.0, "> 0"),
                                              ("map_pitch_mm", -2.5, "> 0")])
def test_map_size_settings_are_checked(key, value, rule):
    from lesscli.errors import LessError
    from lesscli.train.config import PretrainConfig, check_pretrain_config

    cfg = PretrainConfig()
    cfg.model.name = "less-taxel"
    setattr(cfg.model, key, value)
    with pytest.raises(LessError, match=f"model.{key} = {value!r} is invalid: must be {rule}"):
        check_pretrain_config(cfg)
