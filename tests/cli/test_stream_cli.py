"""``less stream`` through real subprocess pipes: replay, live JSON lines, malformed input, monitor frames."""

from __future__ import annotations

import json

import numpy as np
import pytest
from factories import random_scanset
from imaging_factory import save_tiny_imager

from lesscli.io.scans import save_scans


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("stream")
    save_tiny_imager(str(folder / "im.pt"))
    scans = random_scanset(n_scans=2, traj_per_scan=3, max_len=6, seed=4)
    save_scans(str(folder / "s.npz"), scans)
    return folder, scans


def _records(proc) -> list[dict]:
    return [json.loads(line) for line in proc.stdout.decode().splitlines() if line.strip()]


def _live_line(rng, t: float) -> str:
    pose = [float(rng.uniform(-20, 20)), float(rng.uniform(-20, 20)), -1.0, 0.0, 0.0, 0.3]
    return json.dumps({"t": t, "pose": pose, "force": rng.normal(0, 1, (30, 3)).round(4).tolist()})


def test_replay_matches_batch_prediction_and_writes_frames(files, run_less, tmp_path):
    folder, scans = files
    proc = run_less("stream", folder / "im.pt", folder / "s.npz", "--emit-every", "4", "-o", tmp_path / "fr",
                    "--rate", "2000", check=True)
    rows = _records(proc)
    offsets = scans.scan_step_offsets()
    finals = [max((r for r in rows if r["scan"] == s), key=lambda r: r["step"]) for s in range(scans.n_scans)]
    assert [f["step"] for f in finals] == list(np.diff(offsets))
    assert all(r["frame"] and (tmp_path / "fr" / r["frame"].split("/")[-1]).exists() for r in rows)
    assert "latency p50" in proc.stderr.decode() and f"{scans.n_steps} updates" in proc.stderr.decode()
    run_less("image", "predict", folder / "im.pt", folder / "s.npz", "-o", tmp_path / "pred.npz", check=True)
    from lesscli.io.predictions import load_predictions

    preds = load_predictions(str(tmp_path / "pred.npz"))
    for final, pred in zip(finals, preds.scans):
        assert final["inclusion_voxels"] == int((pred.label == 3).sum())
        assert final["entropy_mean_nats"] == pytest.approx(float(pred.entropy.astype(np.float64).mean()),
                                                           abs=2e-3)


def test_live_malformed_lines_are_reported_with_their_number_and_skipped(files, run_less):
    folder, _ = files
    rng = np.random.default_rng(0)
    lines = [_live_line(rng, 0.0), "{not json", _live_line(rng, 0.02),
             json.dumps({"t": 0.03, "pose": [1, 2, 3]}), "",
             json.dumps({"t": 0.04, "pose": [0, 0, -1, 0, 0, 0], "force": [[1, 2, 3]]}),
             json.dumps({"t": "soon", "pose": [0, 0, -1, 0, 0, 0], "force": [[0, 0, 1]] * 30}),
             _live_line(rng, 0.05)]
    proc = run_less("stream", folder / "im.pt", "-", "--emit-every", "2", input="\n".join(lines).encode())
    err = proc.stderr.decode()
    assert proc.returncode == 0, err
    for number, what in ((2, "not JSON"), (4, "missing 'force'"), (6, "'force' has 3 values"),
                         (7, "'t' must be")):
        assert f"line {number}: {what}" in err
    rows = _records(proc)
    assert [r["step"] for r in rows] == [2, 3] and rows[-1]["t"] == 0.05
    assert "3 updates" in err


def test_live_stop_on_error_exits_1_without_traceback(files, run_less):
    folder, _ = files
    rng = np.random.default_rng(1)
    text = "\n".join([_live_line(rng, 0.0), _live_line(rng, 0.01), "[1, 2]", _live_line(rng, 0.03)])
    proc = run_less("stream", folder / "im.pt", "-", "--emit-every", "1", "--on-error", "stop",
                    input=text.encode())
    err = proc.stderr.decode()
    assert proc.returncode == 1
    assert "line 3: expected a JSON object" in err and "Traceback" not in err
    assert [r["step"] for r in _records(proc)] == [1, 2]


def test_stream_bad_model_is_one_line_error(files, run_less, tmp_path):
    folder, _ = files
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    proc = run_less("stream", tmp_path / "junk.pt", folder / "s.npz")
    assert proc.returncode == 1
    assert "junk.pt" in proc.stderr.decode() and "Traceback" not in proc.stderr.decode()


def test_bench_stream_tiny_run_and_bad_input(run_less):
    proc = run_less("bench", "stream", "--steps", "20,40", "--updates", "3", "--full-repeats", "1", "--dim",
                    "2", "--width", "8,16", "--threads", "1", "--format", "jsonl", check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [(r["width"], r["steps"]) for r in rows] == [(8, 20), (8, 40), (16, 20), (16, 40)]
    for r in rows:
        assert r["dim"] == 2 and r["updates"] == 3 and r["threads"] == 1
        assert 0 < r["incremental_median_ms"] <= r["incremental_p99_ms"]
        assert (r["full_median_ms"] > 0
                and r["speedup_median"] == r["full_median_ms"] / r["incremental_median_ms"])
        assert r["deferred_refresh10_mean_ms"] > 0 and r["particles_per_update"] > 0
    assert all("rate_hz" not in r for r in rows)              # back to back unless --rate
    bad = run_less("bench", "stream", "--steps", "0,5")
    assert bad.returncode == 2 and ">= 1" in bad.stderr.decode()
    slower = run_less("bench", "stream", "--rate", "-5", "--steps", "5")
    assert slower.returncode == 2 and "--rate" in slower.stderr.decode()
    narrow = run_less("bench", "stream", "--width", "4", "--steps", "5")
    assert narrow.returncode == 2 and ">= 8" in narrow.stderr.decode()
    both = run_less("bench", "stream", "--width", "16", "--model", "m.pt", "--steps", "5")
    assert both.returncode == 2 and "--width" in both.stderr.decode()
    missing = run_less("bench", "stream", "--model", "nope.pt", "--steps", "5")
    err = missing.stderr.decode().strip()
    assert missing.returncode == 1 and "nope.pt" in err and len(err.splitlines()) == 1


def test_stream_and_guide_label_with_the_models_rule(files, run_less, tmp_path):
    """The labelling rule stored in the checkpoint (threshold, smallest kept inclusion region) is the one
    ``stream`` and ``guide`` use, as ``image predict`` does; ``--threshold``/``--min-volume-mm3`` override
    it."""
    from imaging_factory import tiny_imager

    from lesscli.io.checkpoint import save_checkpoint

    folder, scans = files
    imager, stats, config = tiny_imager(gain=4.0)
    config["image"].update(threshold=None, min_volume_mm3=1e9)        # every inclusion region is too small
    save_checkpoint(str(tmp_path / "rule.pt"), imager.state_dict(), config, stats, [])

    def final_inclusion(*opts):
        rows = _records(run_less("stream", tmp_path / "rule.pt", folder / "s.npz", *opts, check=True))
        return [max((r for r in rows if r["scan"] == s), key=lambda r: r["step"])["inclusion_voxels"]
                for s in range(scans.n_scans)]

    kept = final_inclusion("--min-volume-mm3", "0")
    assert sum(kept) > 0, "the test model must mark some inclusion for the rule to matter"
    assert final_inclusion() == [0] * scans.n_scans
    run_less("image", "predict", tmp_path / "rule.pt", folder / "s.npz", "-o", tmp_path / "p.npz",
             "--min-volume-mm3", "0", check=True)
    from lesscli.io.predictions import load_predictions

    assert kept == [int((p.label == 3).sum()) for p in load_predictions(str(tmp_path / "p.npz")).scans]

    from lesscli.infer.guide import GuideOptions, guide_scan

    opts = GuideOptions(2, None, None, 3.0, "entropy")
    ckpt = {"config": config, "norm_stats": stats}
    assert not (guide_scan(imager, ckpt, scans, 0, opts).labels == 3).any()
    assert (guide_scan(imager, ckpt, scans, 0, opts, min_volume_mm3=0.0).labels == 3).sum() == kept[0]


def test_stream_guide_and_predict_smooth_as_the_model_says(files, run_less, tmp_path):
    """A model whose stored rule smooths (smooth_mm) labels the same voxels in ``stream``, ``guide`` and
    ``image predict``; ``--smooth-mm 0`` turns it off and labels otherwise."""
    from imaging_factory import tiny_imager

    from lesscli.infer.guide import GuideOptions, guide_scan
    from lesscli.io.checkpoint import save_checkpoint
    from lesscli.io.predictions import load_predictions

    folder, scans = files
    imager, stats, config = tiny_imager(gain=4.0)
    config["image"].update(threshold=None, min_volume_mm3=0.0, smooth_mm=3.0)
    save_checkpoint(str(tmp_path / "smooth.pt"), imager.state_dict(), config, stats, [])

    def counts(*opts):
        rows = _records(run_less("stream", tmp_path / "smooth.pt", folder / "s.npz", *opts, check=True))
        streamed = [max((r for r in rows if r["scan"] == s), key=lambda r: r["step"])["inclusion_voxels"]
                    for s in range(scans.n_scans)]
        run_less("image", "predict", tmp_path / "smooth.pt", folder / "s.npz", "-o", tmp_path / "p.npz",
                 *opts, check=True)
        predicted = [int((p.label == 3).sum()) for p in load_predictions(str(tmp_path / "p.npz")).scans]
        assert streamed == predicted
        return predicted

    smooth, plain = counts(), counts("--smooth-mm", "0")
    assert sum(plain) > 0 and smooth != plain, "the test model must mark inclusion edges that smoothing moves"
    ckpt = {"config": config, "norm_stats": stats}
    opts = GuideOptions(2, None, None, 3.0, "entropy")
    assert (guide_scan(imager, ckpt, scans, 0, opts).labels == 3).sum() == smooth[0]
    assert (guide_scan(imager, ckpt, scans, 0, opts, smooth_mm=0.0).labels == 3).sum() == plain[0]


def test_bench_stream_paced_samples_arrive_at_the_rate():
    """--rate: each timed sample waits for its due time, so the timed loop lasts at least (n - 1) / rate
    (a lower bound: a slower machine only lengthens it); the row reports the share over the period."""
    import time

    import numpy as np

    from lesscli.bench.stream import default_imager, measure

    imager, stats = default_imager(2, 0, width=8)
    t0 = time.perf_counter()
    row = measure(imager, stats, 20, 6, 1, np.random.default_rng(0), rate_hz=25.0)
    assert time.perf_counter() - t0 >= 5 / 25.0
    assert row["rate_hz"] == 25.0 and 0.0 <= row["over_period_share"] <= 1.0 and row["updates"] == 6
