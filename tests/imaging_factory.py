"""Imaging test data: a tiny learnable scan set (the pad feels more force near the inclusion) and tiny
randomly initialised imagers with the checkpoint config that rebuilds them."""

from __future__ import annotations

import numpy as np
import torch
from factories import sphere_labels

from lesscli.io.scans import ScanSet, default_meta
from lesscli.io.sensor import xela_uscu
from lesscli.models.encoders import GlobalEncoder, ParticleEncoder
from lesscli.models.imager import Imager, grid_to_dict
from lesscli.models.registry import build_decoder
from lesscli.types import ImageGrid

SMALL_SHAPE = (6, 32, 32)
SMALL_SPACING_MM = (2.0, 1.9, 1.9)        # the 61 mm field of view at a quarter of the resolution
INCLUSION_RADIUS_MM = 6.0
INCLUSION_DEPTH_MM = -6.0
TOUCH_X_MM = (-28.0, 2.0)                 # touches never reach x > 2 mm: the right side stays untouched
BUMP_N, BUMP_WIDTH_MM = 3.0, 5.0


def learnable_scanset(n_scans: int, seed: int, steps_per_traj: int = 8, traj_per_scan: int = 12,
                      shape=SMALL_SHAPE, spacing=SMALL_SPACING_MM) -> ScanSet:
    """Scans of single spherical inclusions; each press's normal force grows near the inclusion."""
    rng = np.random.default_rng(seed)
    n_traj = n_scans * traj_per_scan
    centres = np.stack([rng.uniform(-18, -2, n_scans), rng.uniform(-12, 12, n_scans)], axis=1)
    pose = np.zeros((n_traj, steps_per_traj, 6), np.float32)
    xy = np.stack([rng.uniform(*TOUCH_X_MM, n_traj), rng.uniform(-25, 25, n_traj)], axis=1)
    pose[:, :, :2] = xy[:, None, :] + rng.normal(0, 0.3, (n_traj, steps_per_traj, 2))
    depth = np.linspace(0.2, 3.0, steps_per_traj)
    pose[:, :, 2] = -depth
    scan_of = np.repeat(np.arange(n_scans), traj_per_scan)
    d2 = ((pose[:, :, :2] - centres[scan_of][:, None, :]) ** 2).sum(-1)
    stiff = 1.0 + BUMP_N * np.exp(-d2 / (2 * BUMP_WIDTH_MM**2))
    force = rng.normal(0, 0.02, (n_traj, steps_per_traj, 30, 3)).astype(np.float32)
    force[..., 2] += (0.5 * depth[None, :] * stiff)[..., None]
    labels = [sphere_labels(center_mm=(INCLUSION_DEPTH_MM, c[1], c[0]), radius_mm=INCLUSION_RADIUS_MM,
                            shape=shape, spacing=spacing, name=f"Sph{i}_0") for i, c in enumerate(centres)]
    n = n_traj * steps_per_traj
    return ScanSet(
        pose=pose.reshape(n, 6), force=force.reshape(n, 30, 3),
        time_s=np.tile(np.arange(steps_per_traj) * 0.5, n_traj),
        traj_offsets=np.arange(n_traj + 1, dtype=np.int64) * steps_per_traj,
        traj_scan=scan_of.astype(np.int64), scan_insert=np.array([f"Sph{i}" for i in range(n_scans)]),
        scan_orientation=np.zeros(n_scans, np.int64), scan_label=np.arange(n_scans, dtype=np.int64),
        labels=labels, meta=default_meta(xela_uscu()))


def make_representation(path: str, scans: ScanSet, name: str = "less", dim: int = 16, seed: int = 0) -> None:
    """An untrained representation checkpoint (as 'less pretrain' writes) for fast imaging tests."""
    import torch

    from lesscli.data.batching import compute_norm_stats
    from lesscli.io.checkpoint import save_checkpoint
    from lesscli.models.registry import ENCODERS

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        encoder = ENCODERS[name](force_dim=scans.n_taxels * 3, dim=dim)
    state = {f"encoder.{k}": v for k, v in encoder.state_dict().items()}
    save_checkpoint(path, state, {"encoder": encoder.config()}, compute_norm_stats(scans), [])


# ------------------------------------------------------------ tiny random imagers (stream, guide, CLI)

FORCE_DIM = 90                      # 30 taxels x 3, the default sensor
SPACING_MM, EXTENT_MM, RADIUS_MM = 6.0, 36.0, 10.0
HALF_MM = 18.0                      # outermost particle row/column


def tiny_imager(dim: int = 2, cap: int | None = None, encoder: str = "less", seed: int = 0,
                grid: ImageGrid | None = None, gain: float = 8.0, stitch: str = "sum",
                context: int = 0) -> tuple[Imager, dict, dict]:
    """A randomly initialised imager, its norm stats, and the checkpoint config that rebuilds it.

    ``gain`` scales the decoder's last layer so logits are O(10) and a 1e-4 tolerance is strict.
    """
    grid = grid or ImageGrid((3 if dim == 3 else 1, 48, 48), (-1.8 if dim == 3 else 0.0, -23.5, -23.5),
                             (0.9, 1.0, 1.0))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        if encoder == "less":
            enc = ParticleEncoder(FORCE_DIM, dim=8, spacing_mm=SPACING_MM, grid_extent_mm=EXTENT_MM,
                                  receptive_field_mm=RADIUS_MM, max_steps_per_particle=cap, n_freq=4)
            dec = {"name": "patch", "d_z": 8, "n_classes": 4, "dim": dim, "width": 8, "patch_px": 8,
                   "depth_px": grid.shape[0], "patch_spacing_mm": [0.9, 1.0, 1.0], "stitch": stitch,
                   **({"context": context} if context else {})}
        else:
            if encoder == "global-taxel":
                from lesscli.io.sensor import xela_uscu
                from lesscli.models.global_taxel import GlobalTaxelEncoder

                enc = GlobalTaxelEncoder(FORCE_DIM, xela_uscu()["taxel_xy_mm"], dim=8, grid_extent_mm=40.0,
                                         map_pitch_mm=5.0, max_steps_per_particle=cap, n_freq=4)
            else:
                enc = GlobalEncoder(FORCE_DIM, dim=8, max_steps_per_particle=cap, n_freq=4)
            dec = {"name": "global", "d_z": enc.dim, "n_classes": 4, "dim": dim, "width": 8,
                   "shape": list(grid.shape)}
        decoder = build_decoder(dec, seed)
    last = [m for m in decoder.modules()
            if isinstance(m, (torch.nn.ConvTranspose2d, torch.nn.ConvTranspose3d))][-1]
    with torch.no_grad():
        last.weight.mul_(gain)
        last.bias.mul_(gain)
    imager = Imager(enc, decoder, grid).eval()
    rng = np.random.default_rng(seed)
    stats = {"force_mean": rng.normal(0, 0.1, FORCE_DIM).tolist(),
             "force_std": rng.uniform(0.5, 2.0, FORCE_DIM).tolist(), "n_steps": 100, "force_units": "N"}
    config = {"encoder": enc.config(), "decoder": dec, "grid": grid_to_dict(grid),
              "image": {"dim": dim, "slice": -1}}
    return imager, stats, config


def save_tiny_imager(path: str, **kwargs) -> None:
    """Write a tiny imaging checkpoint (see :func:`tiny_imager`)."""
    from lesscli.io.checkpoint import save_checkpoint

    imager, stats, config = tiny_imager(**kwargs)
    save_checkpoint(path, imager.state_dict(), config, stats, [])
