"""`less bench mri`: the full pipeline against plain thresholding, and `--knobs`, one row per setting of each
of
mri-label's knobs against the defaults timed in the same run (a 48^3 volume: seconds, not minutes)."""

from __future__ import annotations

import json
import math

from lesscli.bench.mri import KNOBS


def _rows(proc) -> list[dict]:
    return [json.loads(line) for line in proc.stdout.decode().splitlines()]


def test_bench_mri_rows(run_less):
    rows = _rows(run_less("bench", "mri", "--size", "48", "--format", "jsonl", check=True))
    full, base, first, synth = rows
    assert full["shape"] == "48x48x48" and base["ratio_vs_threshold"] == 1.0
    assert math.isclose(full["ratio_vs_threshold"], full["seconds"] / base["seconds"])
    assert "first call" in first["case"] and math.isclose(first["ratio_vs_threshold"],
                                                          first["seconds"] / base["seconds"])
    assert all(0.9 <= full[f"dice_{c}"] <= 1.0
               for c in ("insert", "pillar", "inclusion")) and full["warnings"] == 0
    assert synth["seconds"] > 0


def test_bench_mri_knobs_rows_and_plot(run_less, tmp_path):
    rows = _rows(run_less("bench", "mri", "--knobs", "--size", "48", "--plot", "knobs.png", "--format",
                          "jsonl", check=True))
    assert [(r["knob"], r["value"]) for r in rows] == [(k, v) for k, values in KNOBS.items() for v in values]
    defaults = [r for r in rows if r["default"]]
    assert [r["knob"] for r in defaults] == list(KNOBS)
    assert all(r["ratio_vs_default"] == 1.0 and r["dice_pillar_delta"] == 0.0 for r in defaults)
    assert len({r["seconds"] for r in defaults}) == 1              # the defaults' one measurement
    for r in rows:
        assert r["seconds"] > 0 and math.isclose(r["ratio_vs_default"], r["seconds"] / defaults[0]["seconds"])
        assert all(0.0 <= r[f"dice_{c}"] <= 1.0 for c in ("insert", "pillar", "inclusion"))
        assert math.isclose(r["dice_inclusion_delta"], r["dice_inclusion"] - defaults[0]["dice_inclusion"])
    assert (tmp_path / "knobs.png").stat().st_size > 1000


def test_bench_mri_plot_needs_knobs(run_less, tmp_path):
    proc = run_less("bench", "mri", "--size", "48", "--plot", "x.png")
    assert proc.returncode == 2 and "--plot needs --knobs" in proc.stderr.decode()
    assert not (tmp_path / "x.png").exists()
