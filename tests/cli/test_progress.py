"""Progress for logs: where stderr is not a terminal, plain lines (one per epoch, or per 10 % of the work),
never cursor codes; -q silences them. The line rule is table-tested on :class:`PlainProgress`; the commands
run as real subprocesses writing to a pipe, as a batch job's log would."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest
from factories import TINY_SCENE, random_scanset

from lesscli.cli.progress import PlainProgress
from lesscli.io.scans import save_scans

LESS = str(Path(sys.executable).parent / "less")
CURSOR = ("\r", "\x1b")


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _lines(**kwargs) -> list[str]:
    out, clock = io.StringIO(), Clock()
    items = kwargs.pop("items")
    bar = PlainProgress(items, file=out, clock=clock, **kwargs)
    for _ in bar:
        clock.t += 1.0
        bar.set_postfix(loss="0.5")
    bar.close()
    return out.getvalue().splitlines()


def test_an_epoch_bar_writes_one_line_per_epoch_with_its_figures():
    lines = _lines(items=range(3), desc="train", unit="epoch")
    assert lines == ["less: train: epoch 1/3, 1.0 s elapsed, ETA 2.0 s, loss=0.5",
                     "less: train: epoch 2/3, 2.0 s elapsed, ETA 1.0 s, loss=0.5",
                     "less: train: epoch 3/3, 3.0 s elapsed, loss=0.5"]


@pytest.mark.parametrize("n, expected", [(100, 10), (25, 10), (7, 7), (3, 3), (1, 1)])
def test_other_bars_write_a_line_per_10_percent(n, expected):
    lines = _lines(items=range(n), desc="scans", unit="scan")
    assert len(lines) == expected and lines[-1].startswith(f"less: scans: {n}/{n} scans (100 %)")


def test_a_bar_without_a_total_writes_at_the_end_and_at_most_every_30_s():
    lines = _lines(items=iter(range(100)), desc="detect")
    assert len(lines) == 3 + 1 and lines[-1] == "less: detect: 100 steps, 1 min 40 s elapsed, loss=0.5"


def test_byte_counts_are_sized():
    out, clock = io.StringIO(), Clock()
    with PlainProgress(total=4 << 20, unit="B", unit_scale=True, unit_divisor=1024, desc="a.zip", file=out,
                       clock=clock) as bar:
        bar.update(1 << 20)
        bar.update(3 << 20)
    assert out.getvalue().splitlines() == ["less: a.zip: 1.0 MiB/4.0 MiB (25 %), 0.0 s elapsed, ETA 0.0 s",
                                           "less: a.zip: 4.0 MiB/4.0 MiB (100 %), 0.0 s elapsed"]


def _run(args, cwd):
    return subprocess.run([LESS, *args], cwd=cwd, capture_output=True, text=True, timeout=600, check=False)


def test_training_in_a_log_shows_each_epoch_and_verbose_adds_no_cursor_codes(tmp_path):
    save_scans(str(tmp_path / "s.npz"), random_scanset())
    proc = _run(["pretrain", "s.npz", "-o", "r.pt", "--epochs", "3", "--dim", "8", "--format", "jsonl"],
                tmp_path)
    assert proc.returncode == 0, proc.stderr
    epochs = [line for line in proc.stderr.splitlines() if line.startswith("less: train: epoch ")]
    assert [line.split(",")[0] for line in epochs] == [f"less: train: epoch {i}/3" for i in (1, 2, 3)]
    assert all("loss=" in line and "best_loss=" in line for line in epochs)
    loud = _run(["-v", "pretrain", "s.npz", "-o", "v.pt", "--epochs", "2", "--dim", "8", "--format", "jsonl"],
                tmp_path)
    assert loud.returncode == 0 and not any(c in loud.stderr for c in CURSOR)
    assert "less: epoch 1/2: " in loud.stderr                   # -v: the batches of each epoch, as lines too
    quiet = _run(["-q", "pretrain", "s.npz", "-o", "q.pt", "--epochs", "2", "--dim", "8", "--format",
                  "jsonl"],
                 tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == ""


def test_simulate_in_a_log_shows_its_scans_by_tenths(tmp_path):
    (tmp_path / "tiny.toml").write_text(TINY_SCENE)
    proc = _run(["simulate", "tiny.toml", "-o", "x.npz", "--jobs", "1", "--format", "jsonl"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert lines == [f"less: scans: {i}/4 scans ({25 * i} %)" + lines[i - 1].split("%)", 1)[1]
                     for i in (1, 2, 3, 4)]
    assert not any(c in proc.stderr for c in CURSOR)


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pseudo-terminal")
def test_a_terminal_still_gets_a_bar(tmp_path):
    (tmp_path / "tiny.toml").write_text(TINY_SCENE)
    leader, follower = os.openpty()
    try:
        proc = subprocess.run([LESS, "simulate", "tiny.toml", "-o", "x.npz", "--jobs", "1", "--format",
                               "jsonl"],
                              cwd=tmp_path, stdout=subprocess.PIPE, stderr=follower, timeout=600, check=False)
        os.close(follower)
        follower = None
        seen = b""
        os.set_blocking(leader, False)
        try:
            while chunk := os.read(leader, 65536):
                seen += chunk
        except (BlockingIOError, OSError):
            pass
    finally:
        if follower is not None:
            os.close(follower)
        os.close(leader)
    assert proc.returncode == 0 and b"\r" in seen and b"less: scans:" not in seen
