"""Another sensor end to end: a 4 x 4 pad at 3.5 mm pitch and a single-taxel force probe (their scenes in
examples/scenes/) through simulate -> subsample -> pretrain -> image fit -> predict -> metrics, with
less-taxel and the classical force map, at tiny sizes."""

from __future__ import annotations

import json

import pytest
from factories import REPO

TINY = ["--set", "phantoms.random.count=4", "--set", "motion.n_traj=10", "--set", "labels.shape=[6,16,16]",
        "--set", "labels.spacing_mm=[3.0,4.0,4.0]"]


@pytest.mark.parametrize("scene,taxels", [("pad4x4", 16), ("probe", 1)])
def test_the_pipeline_runs_on_another_sensor(run_less, tmp_path, scene, taxels):
    run_less("simulate", REPO / "examples" / "scenes" / f"{scene}.toml", "-o", "raw.npz", *TINY, check=True)
    run_less("subsample", "raw.npz", "--every", "50", "-o", "s.npz", check=True)
    from lesscli.io.scans import load_scans

    scans = load_scans(str(tmp_path / "s.npz"))
    assert scans.n_taxels == taxels and scans.meta["sensor"]["name"] in ("pad-4x4", "probe")
    assert scans.meta["sensor"]["noise_n"] == 0.005
    run_less("pretrain", "s.npz", "-o", "rep.pt", "--model", "less-taxel", "--dim", "8", "--epochs", "1",
             "--set", "ssl.k_input=4", "--set", "ssl.k_query=4", check=True)
    run_less("image", "fit", "s.npz", "--rep", "rep.pt", "-o", "im.pt", "--dim", "3", "--epochs", "1",
             "--set", "image.patch_px=16", "--set", "image.width=8", check=True)
    run_less("image", "fit", "s.npz", "--model", "forcemap", "-o", "fm.pt", check=True)
    run_less("image", "predict", "im.pt", "s.npz", "-o", "p.npz", check=True)
    run_less("image", "predict", "fm.pt", "s.npz", "-o", "pf.npz", check=True)
    proc = run_less("metrics", "p.npz", "pf.npz", "--group-by", "model", "--summary-only", "--format",
                    "jsonl", check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines() if line.strip()]
    assert {r["model"] for r in rows} == {"forcemap", "less-taxel"}
    info = json.loads(run_less("info", "im.pt", "fm.pt", "--format", "json", check=True).stdout)
    name = scans.meta["sensor"]["name"]
    assert [(r["pose_frame"], r["sensor"]) for r in info] == [("surface", f"{name} ({taxels} taxels)")] * 2
    # the checkpoints carry the sensor: the default 30-taxel scans are refused by both
    from factories import random_scanset

    from lesscli.io.scans import save_scans

    save_scans(str(tmp_path / "xela.npz"), random_scanset())
    for model in ("im.pt", "fm.pt"):
        bad = run_less("image", "predict", model, "xela.npz", "-o", "x.npz")
        assert bad.returncode == 1 and f"30 taxels vs {taxels} taxels" in bad.stderr.decode()
        assert not (tmp_path / "x.npz").exists()
