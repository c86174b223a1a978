"""``less bench train``: one training step and one inference forward of LESS and GLOBAL, timed on
synthetic scans.

Sizes: ``default`` (this toolkit's defaults: d_z 128, 11 x 11 particles at 6 mm) and ``paper``
(d_z 1024, 18 x 18 particles, as in the paper), both on scans of ``steps`` pad poses spread over
the phantom. GLOBAL at the same d_z is the in-run baseline for the ratios. The SSL loss draws
``ssl.k_input`` x ``ssl.k_query`` pairs per particle (:class:`BenchConfig`; the paper's sweeps use 8 x 8).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import torch

from lesscli.models.encoders import GlobalEncoder, ParticleEncoder
from lesscli.models.force_decoder import ForceDecoder
from lesscli.models.ssl_loss import ForcePredictor
from lesscli.train.config import SSLConfig, check_sections, load_config
from lesscli.types import Batch

FORCE_DIM = 90
PHANTOM_HALF_WIDTH_MM = 30.0


@dataclass
class Size:
    name: str
    dim: int
    particles_per_axis: int
    spacing_mm: float = 6.0


SIZES = {"default": Size("default", 128, 11), "paper": Size("paper", 1024, 18)}


@dataclass
class BenchConfig:
    """The settings ``less bench train --set`` may change."""

    ssl: SSLConfig = field(default_factory=SSLConfig)


def bench_config(overrides: tuple[str, ...] = ()) -> BenchConfig:
    """Defaults < ``--set`` pairs (``ssl.k_input=8``), checked like pretraining's."""
    return check_sections(load_config(BenchConfig, None, overrides), ("ssl",))


def synthetic_batch(batch: int, steps: int, generator: torch.Generator) -> Batch:
    """Random pad poses over the phantom (10-step pokes) with random normalised forces."""
    pokes = max(1, steps // 10)
    xy = (torch.rand(batch, pokes, 1, 2, generator=generator) * 2 - 1) * PHANTOM_HALF_WIDTH_MM
    pose = torch.zeros(batch, pokes, 10, 6)
    pose[..., :2] = xy.expand(-1, -1, 10, -1)
    pose[..., 2] = -torch.linspace(0, 4, 10)
    pose = pose.reshape(batch, pokes * 10, 6)[:, :steps]
    force = torch.randn(batch, pose.shape[1], FORCE_DIM, generator=generator)
    valid = torch.ones(batch, pose.shape[1], dtype=torch.bool)
    return Batch(pose=pose, force=force, valid=valid, scan_index=torch.arange(batch))


def build(model: str, size: Size, seed: int = 0, ssl: SSLConfig | None = None) -> ForcePredictor:
    """LESS (with exactly ``particles_per_axis`` squared particles) or GLOBAL at ``size``."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        if model == "global":
            encoder = GlobalEncoder(FORCE_DIM, size.dim)
        else:
            encoder = ParticleEncoder(FORCE_DIM, size.dim, spacing_mm=size.spacing_mm,
                                      particles_per_axis=size.particles_per_axis)
        ssl = ssl or SSLConfig()
        return ForcePredictor(encoder, ForceDecoder(FORCE_DIM, size.dim), ssl.k_input, ssl.k_query)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _timed(fn, device: torch.device, repeats: int) -> tuple[float, float]:
    """(wall seconds, process CPU seconds) per call, after one warm-up call."""
    fn()                                               # warm-up (allocations, kernels)
    _sync(device)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(repeats):
        fn()
    _sync(device)
    return (time.perf_counter() - t0) / repeats, (time.process_time() - c0) / repeats


def measure(model: str, size: Size, steps: int, batch: int, repeats: int, device: torch.device,
            ssl: SSLConfig | None = None) -> dict:
    """Seconds per training step (forward, backward, Adam) and per inference forward (final states).

    Wall time, and the process's CPU time (less sensitive to other load on a shared machine).
    """
    net = build(model, size, ssl=ssl).to(device)
    data = synthetic_batch(batch, steps, torch.Generator().manual_seed(1)).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    gen = torch.Generator().manual_seed(2)

    def train_step() -> None:
        opt.zero_grad(set_to_none=True)
        net(data, gen).backward()
        opt.step()

    def forward() -> None:
        with torch.no_grad():
            net.encoder(data)

    net.train()
    train_s, train_cpu_s = _timed(train_step, device, repeats)
    net.eval()
    forward_s, forward_cpu_s = _timed(forward, device, repeats)
    seen = net.encoder(data).seen if model == "less" else None
    return {"size": size.name, "model": model, "d_z": size.dim, "particles": net.encoder.n_particles,
            "particles_seen": float(seen.sum(1).float().mean()) if seen is not None else 1.0,
            "steps": steps, "batch": batch, "k_input": net.k_input, "k_query": net.k_query,
            "parameters": sum(p.numel() for p in net.parameters()),
            "encoder_parameters": sum(p.numel() for p in net.encoder.parameters()),
            "train_step_s": train_s, "forward_s": forward_s, "train_step_cpu_s": train_cpu_s,
            "forward_cpu_s": forward_cpu_s, "device": str(device)}


def run(sizes: list[str], steps: int, batch: int, repeats: int, device: torch.device,
        cfg: BenchConfig | None = None) -> list[dict]:
    """Rows for LESS and GLOBAL at each size, with LESS / GLOBAL time ratios."""
    ssl = (cfg or BenchConfig()).ssl
    rows = []
    for name in sizes:
        base = measure("global", SIZES[name], steps, batch, repeats, device, ssl)
        less = measure("less", SIZES[name], steps, batch, repeats, device, ssl)
        for row in (base, less):
            row["train_vs_global"] = row["train_step_s"] / base["train_step_s"]
            row["forward_vs_global"] = row["forward_s"] / base["forward_s"]
            rows.append(row)
    return rows
