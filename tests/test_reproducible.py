"""Reproducible by default: the same command writes the same bytes, whatever else the machine runs.

The thread count no longer follows the machine's load (lesscli.threads), archives carry no clock time
(lesscli.io.npfiles.write_npz), checkpoints keep the epochs' wall-clock seconds in the log only, and
``SOURCE_DATE_EPOCH`` fixes the time a history entry records. So a pipeline of ``simulate``,
``pretrain``, ``image fit`` and ``image predict`` at tiny sizes is run twice, alone and beside two busy
processes, each time in a fresh folder through the installed console script, and every output is
compared byte for byte.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
from factories import TINY_SCENE

from lesscli.bench.timing import busy_processes

BIN = Path(sys.executable).parent
EPOCH = "1700000000"
OUTPUTS = ("raw.npz", "rep.pt", "im.pt", "pred.npz")
PIPELINE = [
    ["simulate", "tiny.toml", "-o", "raw.npz", "--jobs", "2"],
    ["pretrain", "raw.npz", "-o", "rep.pt", "--epochs", "2", "--dim", "8", "--spacing-mm", "8"],
    ["image", "fit", "raw.npz", "--rep", "rep.pt", "-o", "im.pt", "--epochs", "2", "--set", "image.width=8"],
    ["image", "predict", "im.pt", "raw.npz", "-o", "pred.npz", "--steps", "2"],
]


def _environment(**extra) -> dict:
    """The user's environment without a thread setting of its own, and a fixed history time."""
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                             "MKL_NUM_THREADS")}
    return {**env, "PATH": f"{BIN}{os.pathsep}{env.get('PATH', '')}", "SOURCE_DATE_EPOCH": EPOCH, **extra}


def run_pipeline(folder: Path) -> dict[str, str]:
    """Run PIPELINE in ``folder``; the SHA-256 of each output."""
    folder.mkdir()
    (folder / "tiny.toml").write_text(TINY_SCENE)
    for args in PIPELINE:
        proc = subprocess.run([str(BIN / "less"), "-q", *args, "--format", "jsonl"], cwd=folder,
                              env=_environment(), capture_output=True, timeout=900, check=False)
        assert proc.returncode == 0, (args, proc.stderr.decode())
    return {name: hashlib.sha256((folder / name).read_bytes()).hexdigest() for name in OUTPUTS}


@pytest.mark.slow
@pytest.mark.skipif(not os.path.isdir("/proc"), reason="the busy processes are checked through /proc")
def test_the_same_bytes_alone_and_beside_two_busy_processes(tmp_path):
    alone = run_pipeline(tmp_path / "alone")
    with busy_processes(2):
        busy = run_pipeline(tmp_path / "busy")
    assert busy == alone


def test_a_rerun_of_simulate_writes_the_same_bytes_and_the_fixed_history_time(tmp_path):
    from lesscli.io.scans import load_scans

    (tmp_path / "tiny.toml").write_text(TINY_SCENE)
    for run in ("c", "d"):                  # the same command line in two folders
        (tmp_path / run).mkdir()
        subprocess.run([str(BIN / "less"), "-q", "simulate", "../tiny.toml", "-o", "a.npz", "--format",
                        "jsonl"],
                       cwd=tmp_path / run, env=_environment(), check=True, capture_output=True, timeout=600)
    assert (tmp_path / "c" / "a.npz").read_bytes() == (tmp_path / "d" / "a.npz").read_bytes()
    assert [h["time"] for h in load_scans(str(tmp_path / "c" / "a.npz")).meta["history"]] == \
        ["2023-11-14T22:13:20+0000"]
