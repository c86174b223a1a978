"""`less bench sim` through the installed console script (quick V1 rows only, plus the plot)."""

import json


def test_bench_sim_sphere_rows_and_plot(run_less, tmp_path):
    png = tmp_path / "ladder.png"
    proc = run_less("bench", "sim", "--quick", "--check", "sphere", "--format", "jsonl", "--plot", str(png),
                    check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [r["mesh_mm"] for r in rows] == [2.0, 1.0]
    assert all(r["bench"] == "sim" and r["check"] == "sphere" and r["tier"] == "fem" for r in rows)
    ci = rows[1]
    assert ci["pass"] is True and ci["error"] < 0.12 and ci["ms_per_step"] > 0
    assert png.stat().st_size > 1000


def test_bench_sim_rejects_unknown_check(run_less):
    proc = run_less("bench", "sim", "--check", "spheres")
    assert proc.returncode == 2 and b"spheres" in proc.stderr
