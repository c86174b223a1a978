"""``less bench stream``: per-update latency of incremental imaging vs full recomputation.

For each prefix length L (default 100, 1000 and 5000 steps) the stream is primed with L steps of a
synthetic palpation stream (random touches over the phantom), then the next ``--updates`` samples are
pushed one at a time and each update (receptive-field test, GRU steps, patch re-decode, canvas update)
is timed. The baseline, measured in the same run, is what a non-incremental system does on every new
sample: the whole model on the whole prefix (encoder over all L + 1 steps and every particle's patch).
Wall-clock and process CPU time are both reported: on a shared machine the CPU time is the better
estimate of what an unloaded machine would show. A further column times deferred decoding: samples
only advance GRU states and the image is refreshed every ``REFRESH_EVERY`` samples (mean cost per
sample, refreshes included). With ``--load`` the whole measurement repeats beside N busy processes,
one row per load level; the thread count is the one the ``stream`` command would choose with them
running (unless ``--threads`` fixes it). With ``--rate`` the timed samples arrive at a live sensor's
pace instead of back to back (see :func:`measure`).
"""

from __future__ import annotations

import time

DEFAULT_STEPS = (100, 1000, 5000)
PHANTOM_HALF_MM = 28.0          # touches fall inside the 60 mm phantom, 2 mm from its edge
N_TAXELS = 30
CPU_TICK_S = 1e-6                # floor for CPU-time ratios (process_time resolution)
REFRESH_EVERY = 10              # deferred decoding: one image refresh per 10 samples (10 Hz at 100 Hz)


def default_imager(dim: int, seed: int, width: int | None = None):
    """The default-size model (``less pretrain`` + ``less image fit`` defaults), randomly initialised.

    ``width`` replaces the image decoder's default width (channels of its first feature map).
    """
    import torch

    from lesscli.io.labels import N_CLASSES
    from lesscli.models.encoders import ParticleEncoder
    from lesscli.models.imager import Imager
    from lesscli.models.patch_decoder import PatchDecoder
    from lesscli.train.config import ModelConfig
    from lesscli.train.image_fit import ImageModelConfig
    from lesscli.types import ImageGrid

    m, im = ModelConfig(), ImageModelConfig()
    shape, spacing = (26, 128, 128), (0.9, 0.4774, 0.4774)
    origin = (-(shape[0] - 1) * spacing[0], -(shape[1] - 1) / 2 * spacing[1],
              -(shape[2] - 1) / 2 * spacing[2])
    grid = ImageGrid(shape if dim == 3 else (1, *shape[1:]), origin, spacing)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        enc = ParticleEncoder(N_TAXELS * 3, dim=m.dim, spacing_mm=m.spacing_mm,
                              grid_extent_mm=m.grid_extent_mm, receptive_field_mm=m.receptive_field_mm,
                              n_freq=m.n_freq)
        dec = PatchDecoder(m.dim, N_CLASSES, dim, im.patch_px, shape[0], spacing, width or im.width)
    stats = {"force_mean": [0.0] * (N_TAXELS * 3), "force_std": [1.0] * (N_TAXELS * 3)}
    return Imager(enc, dec, grid).eval(), stats


def synthetic_stream(n: int, rng):
    """(n, 6) poses over the phantom (pokes of 10 steps each) and (n, 30, 3) forces."""
    import numpy as np

    n_poke = -(-n // 10)
    centre = rng.uniform(-PHANTOM_HALF_MM, PHANTOM_HALF_MM, (n_poke, 2))
    pose = np.zeros((n_poke * 10, 6), np.float32)
    pose[:, :2] = np.repeat(centre, 10, axis=0) + rng.normal(0, 0.2, (n_poke * 10, 2))
    pose[:, 2] = -np.tile(np.linspace(0.2, 3.0, 10), n_poke)
    pose[:, 5] = np.repeat(rng.uniform(0, 1.4, n_poke), 10)
    force = rng.normal(0, 0.05, (n_poke * 10, N_TAXELS, 3)).astype(np.float32)
    force[..., 2] += -pose[:, 2:3]
    return pose[:n], force[:n]


def _percentiles(times_s: list[float]) -> tuple[float, float]:
    import numpy as np

    ms = np.asarray(times_s) * 1e3
    return float(np.median(ms)), float(np.percentile(ms, 99))


def measure(imager, stats, steps: int, updates: int, full_repeats: int, rng, rate_hz: float = 0.0) -> dict:
    """One table row: incremental and full per-update latency (ms) after ``steps`` samples.

    With ``rate_hz`` the timed samples arrive as from a live sensor, one every 1 / rate_hz seconds
    (the process sleeps until each is due; after a late update the next starts at once, as from a
    backlog), and ``over_period_share`` is the share of updates that took longer than that period.
    """
    import numpy as np
    import torch

    from lesscli.data.batching import collate
    from lesscli.infer.stream import StreamingImager

    pose, force = synthetic_stream(steps + updates, rng)
    stream = StreamingImager(imager, stats)
    stream.prime(pose[:steps], force[:steps])
    inc, inc_cpu, advanced = [], [], 0
    due = time.perf_counter()
    for i in range(steps, steps + updates):
        if rate_hz:
            due = max(due + 1.0 / rate_hz, time.perf_counter())
            time.sleep(max(due - time.perf_counter(), 0.0))
        c0, t0 = time.process_time(), time.perf_counter()
        advanced += int(stream.push(pose[i], force[i]).numel())
        inc.append(time.perf_counter() - t0)
        inc_cpu.append(time.process_time() - c0)
    deferred = StreamingImager(imager, stats, defer_decode=True)
    deferred.prime(pose[:steps], force[:steps])
    t0 = time.perf_counter()
    for i in range(steps, steps + updates):
        deferred.push(pose[i], force[i])
        if (i - steps + 1) % REFRESH_EVERY == 0:
            deferred.flush()
    deferred.flush()
    deferred_ms = (time.perf_counter() - t0) * 1e3 / updates
    full, full_cpu = [], []
    for r in range(full_repeats):
        k = steps + 1 + r
        item = {"pose": torch.from_numpy(pose[:k]), "force": torch.from_numpy(force[:k].reshape(k, -1)),
                "scan_index": 0}
        c0, t0 = time.process_time(), time.perf_counter()
        with torch.no_grad():
            imager(collate([item]))
        full.append(time.perf_counter() - t0)
        full_cpu.append(time.process_time() - c0)
    inc_med, inc_p99 = _percentiles(inc)
    full_med, full_p99 = _percentiles(full)
    cpu_inc, cpu_full = _percentiles(inc_cpu)[0], _percentiles(full_cpu)[0]
    row = {"bench": "stream", "steps": steps, "incremental_median_ms": inc_med, "incremental_p99_ms": inc_p99,
           "full_median_ms": full_med, "full_p99_ms": full_p99, "speedup_median": full_med / inc_med,
           f"deferred_refresh{REFRESH_EVERY}_mean_ms": deferred_ms, "incremental_cpu_median_ms": cpu_inc,
           "full_cpu_median_ms": cpu_full, "speedup_cpu_median": cpu_full / max(cpu_inc, CPU_TICK_S * 1e3),
           "particles_per_update": advanced / updates, "updates": updates, "full_repeats": full_repeats}
    if rate_hz:
        row.update(rate_hz=rate_hz, over_period_share=float(np.mean(np.asarray(inc) * rate_hz > 1.0)))
    return row


def stream_models(model_path: str | None, dim: int, widths: list[int | None], seed: int) -> list[tuple]:
    """(imager, norm stats, name) to time: the checkpoint at ``model_path``, else the default model at each
    width."""
    if model_path:
        from lesscli.infer.predict import load_imager

        imager, ckpt = load_imager(model_path)
        return [(imager, ckpt["norm_stats"], model_path)]
    return [(*default_imager(dim, seed, w), "default (random init)") for w in widths]


def run_stream(models: list[tuple], steps: list[int], loads: list[int], updates: int, full_repeats: int,
               threads: int | None, seed: int, rate_hz: float = 0.0, realtime: bool = False) -> list[dict]:
    """One row per load level, model and prefix length (see :func:`measure`).

    Beside ``load`` busy processes the thread count is the one the ``stream`` command would choose
    with them running, unless ``threads`` fixes it. ``realtime``: the whole measurement under the
    real-time FIFO policy, as ``stream --realtime`` (the busy processes stay ordinary ones).
    """
    import numpy as np
    import torch

    from lesscli.bench.timing import busy_processes
    from lesscli.realtime import set_realtime
    from lesscli.threads import apply_threads, load_average

    before = load_average()          # the others' load, read before this process's own work adds to it
    if realtime:
        set_realtime()
    rows = []
    for load in loads:
        with busy_processes(load):
            # the stream command's choice once the average counts them
            apply_threads("latency", threads, load=before + load)
            for imager, stats, name in models:
                rng = np.random.default_rng(seed)
                for n in steps:
                    row = measure(imager, stats, n, updates, full_repeats, rng, rate_hz)
                    row.update({"dim": int(imager.grid.shape[0] > 1) + 2,
                                "width": getattr(imager.decoder, "width", None),
                                "threads": torch.get_num_threads(), "load": load, "realtime": realtime,
                                "model": name})
                    rows.append(row)
    return rows
