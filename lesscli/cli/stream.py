"""``less stream MODEL SOURCE``: real-time imaging, one sample at a time (see lesscli.infer.stream)."""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING

import click

from lesscli.cli.common import (
    LATENCY_THREADS,
    checked_output,
    device_option,
    labelling_options,
    realtime_option,
    renamed_option,
    threads_option,
)

if TYPE_CHECKING:
    from lesscli.io.predictions import Labelling

EMIT_DEFAULT = 10
LATENCY_PERCENTILES = (50, 90, 99)


@click.command("stream")
@click.argument("model", type=click.Path())
@click.argument("source", type=click.Path())
@click.option("--rate", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Replay a scan set at this many samples per second (default: as fast as possible).")
@click.option("--emit-every", type=click.IntRange(min=1), default=EMIT_DEFAULT, show_default=True,
              help="Write a record (and a monitor frame) every N samples, and at the end of each scan.")
@renamed_option("--monitor", "-o", "--output", "monitor_dir", type=click.Path(), default=None,
                callback=checked_output(folder=True),
                help="Write PNG frames (image | uncertainty | touches) here.")
@click.option("--on-error", type=click.Choice(["skip", "stop"]), default="skip", show_default=True,
              help="Live input: a malformed line is reported with its line number and skipped, or stops the "
                   "stream.")
@labelling_options()
@click.option("--defer", is_flag=True,
              help="Re-decode patches only when a record is written (same images, faster).")
@device_option()
@threads_option(LATENCY_THREADS)
@realtime_option()
def cli(model, source, rate, emit_every, monitor_dir, on_error, threshold, min_volume_mm3, smooth_mm, defer,
        device, threads, realtime) -> None:
    """Image SOURCE incrementally with the imaging checkpoint MODEL.

    SOURCE is a scan set (each scan replayed from a fresh state, at --rate samples/s or as fast as
    possible) or '-' for live samples on stdin, one JSON object per line:
    {"t": 0.01, "pose": [x, y, z, roll, pitch, yaw], "force": [[fx, fy, fz], ...]} (mm, rad, raw
    sensor units as in the training data). Each sample advances only the particles whose receptive
    field contains it. Every --emit-every samples a JSON line goes to stdout with the entropy summary
    (and a PNG frame to -o DIR); per-update latency percentiles go to stderr at the end.

    Example: less stream imager.pt test.npz --emit-every 50 -o frames/
    """
    import os

    from lesscli.infer.predict import labelling_rule, load_imager
    from lesscli.realtime import set_realtime
    from lesscli.threads import apply_threads
    from lesscli.train.distributed import resolve_device

    dev = resolve_device(device)
    imager, ckpt = load_imager(model, dev)
    apply_threads("latency", threads)
    if realtime:
        set_realtime()
    if monitor_dir:
        os.makedirs(monitor_dir, exist_ok=True)
    emitter = Emitter(emit_every, monitor_dir,
                      labelling_rule(ckpt["config"]["image"], threshold, min_volume_mm3, smooth_mm))
    try:
        if source == "-":
            run_live(imager, ckpt, sys.stdin.buffer, emitter, on_error, defer)
        else:
            replay_scans(imager, ckpt, source, emitter, rate, defer, model)
    finally:
        emitter.report_latency()


class Emitter:
    """Per-sample bookkeeping: latencies, records every N samples, monitor frames."""

    def __init__(self, every: int, monitor_dir: str | None, labelling: Labelling | None = None) -> None:
        from lesscli.io.predictions import Labelling

        self.every, self.monitor_dir = every, monitor_dir
        self.labelling = labelling or Labelling()
        self.latency_s: list[float] = []
        self.scan, self.insert, self.touches, self.last_emitted = 0, "", [], -1
        self.last_t: float | None = None

    def start(self, scan: int, insert: str) -> None:
        self.scan, self.insert, self.touches, self.last_emitted = scan, insert, [], -1
        self.last_t = None

    def sample(self, stream, pose, t: float | None, latency_s: float, advanced: int) -> None:
        """Record one update; write a record when the sample count reaches a multiple of N."""
        self.latency_s.append(latency_s)
        self.last_t = t
        self.touches.append((float(pose[0]), float(pose[1])))
        if stream.n_steps % self.every == 0:
            self.emit(stream, t, latency_s, advanced)

    def finish(self, stream) -> None:
        """Write the final record of a scan (unless the last sample just wrote one)."""
        if stream.n_steps != self.last_emitted:
            self.emit(stream, self.last_t, self.latency_s[-1] if stream.n_steps else None, None)

    def emit(self, stream, t, latency_s, advanced) -> None:
        from lesscli.infer.stream import entropy_summary
        from lesscli.io.labels import INCLUSION
        from lesscli.io.records import dumps

        t0 = time.perf_counter()
        probs = stream.probs()
        refresh_ms = (time.perf_counter() - t0) * 1e3
        ent = stream.entropy()
        labels = self.labelling.labels(probs, stream.grid.spacing_mm)
        row = {"scan": self.scan, "insert": self.insert, "step": stream.n_steps, "t": t,
               "particles_seen": int(stream.seen.sum()), "particles_advanced": advanced,
               **entropy_summary(ent, probs.shape[0]), "inclusion_voxels": int((labels == INCLUSION).sum()),
               "update_ms": None if latency_s is None else latency_s * 1e3, "refresh_ms": refresh_ms,
               "frame": self._frame(stream, labels, ent, probs.shape[0]) if self.monitor_dir else None}
        sys.stdout.write(dumps(row) + "\n")
        sys.stdout.flush()
        self.last_emitted = stream.n_steps

    def _frame(self, stream, labels, ent, n_classes: int) -> str:
        import os

        import numpy as np

        from lesscli.io.atomic import atomic_path
        from lesscli.plots.monitor import monitor_frame

        path = os.path.join(self.monitor_dir, f"frame_s{self.scan:03d}_{stream.n_steps:06d}.png")
        g = stream.grid
        with atomic_path(path, ".png") as tmp:
            monitor_frame(tmp, labels, ent, np.asarray(self.touches, np.float64).reshape(-1, 2), g.origin_mm,
                          g.spacing_mm, n_classes, title=f"{self.insert or 'live'}  step {stream.n_steps}")
        return path

    def report_latency(self) -> None:
        """Per-update latency percentiles on stderr."""
        import numpy as np

        from lesscli.cli.common import STATE

        if STATE.quiet or not self.latency_s:
            return
        ms = np.asarray(self.latency_s) * 1e3
        parts = ", ".join(f"p{q} {np.percentile(ms, q):.2f} ms" for q in LATENCY_PERCENTILES)
        click.echo(f"less: stream: {len(ms)} updates, latency {parts}, max {ms.max():.2f} ms", err=True)


def _push(stream, emitter: Emitter, pose, force, t) -> None:
    t0 = time.perf_counter()
    advanced = stream.push(pose, force)
    emitter.sample(stream, pose, t, time.perf_counter() - t0, int(advanced.numel()))


def replay_scans(imager, ckpt: dict, path: str, emitter: Emitter, rate: float | None, defer: bool,
                 model_name: str = "the model") -> None:
    """Replay every scan of a scan set from a fresh state, paced at ``rate`` samples/s when given (poses in
    the surface fitted over the whole scan, as batch prediction reads them)."""
    from lesscli.data.image_labels import AUTO_SLICE
    from lesscli.infer.predict import scan_grid, scans_for_model
    from lesscli.infer.stream import StreamingImager

    scans = scans_for_model(path, ckpt, model_name)
    image_cfg = ckpt["config"]["image"]
    dim, slice_index = int(image_cfg["dim"]), int(image_cfg.get("slice", AUTO_SLICE))
    offsets = scans.scan_step_offsets()
    for s in range(scans.n_scans):
        grid, _ = scan_grid(scans, s, dim, slice_index, imager.grid)
        stream = StreamingImager(imager, ckpt["norm_stats"], grid, defer_decode=defer)
        emitter.start(s, str(scans.scan_insert[s]))
        start = time.perf_counter()
        for i in range(int(offsets[s]), int(offsets[s + 1])):
            if rate:
                wait = start + (i - offsets[s]) / rate - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
            _push(stream, emitter, scans.pose[i], scans.force[i], float(scans.time_s[i]))
        emitter.finish(stream)


def run_live(imager, ckpt: dict, lines, emitter: Emitter, on_error: str, defer: bool) -> None:
    """Image live JSON lines from ``lines`` (bytes or text); malformed lines, lines that are not UTF-8
    and samples whose time goes backwards are reported with their number. A model that reads the surface
    frame gets each pose on the surface fitted over the onsets of the touches so far
    (:class:`lesscli.data.surface.OnlineSurface`; a touch ends when the pad lifts off)."""
    from lesscli.cli.common import LOG
    from lesscli.errors import DataError
    from lesscli.infer.live import parse_live_line
    from lesscli.infer.stream import StreamingImager

    stream = StreamingImager(imager, ckpt["norm_stats"], defer_decode=defer)
    surface = live_surface(ckpt, stream.force_dim // 3)
    emitter.start(0, "live")
    last_t = None
    for number, text in enumerate(lines, 1):
        if not text.strip():
            continue
        try:
            sample = parse_live_line(text, stream.force_dim, last_t)
        except ValueError as exc:
            if on_error == "stop":
                raise DataError(f"-: line {number}: {exc}; stopping (--on-error stop)") from None
            LOG.warning("-: line %d: %s; skipped", number, exc)
            continue
        last_t = last_t if sample.t is None else sample.t
        pose = sample.pose if surface is None else surface.push(sample.pose, sample.force, sample.t)
        _push(stream, emitter, pose, sample.force, sample.t)
    emitter.finish(stream)


def live_surface(ckpt: dict, taxels: int):
    """The online surface of a model that reads the surface frame (None for one in the phantom frame)."""
    from lesscli.data.compat import model_signature
    from lesscli.data.surface import FRAME, OnlineSurface

    sig = model_signature(ckpt)
    if sig.get("pose_frame") != FRAME:
        return None
    return OnlineSurface({"taxel_xy_mm": sig.get("taxel_xy_mm"), **(sig.get("sensor") or {})}, taxels)
