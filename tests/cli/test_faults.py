"""Faults end cleanly, through the installed console script in real subprocesses: Ctrl-C of a parallel
``simulate`` exits 130 at once; a full disk (a small tmpfs mounted for the test) or an output folder
removed mid-run is one line naming the file, exit 1, nothing left behind; a second writer of an output
refuses at its start."""

from __future__ import annotations

import os
import random
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import popen_interruptible
from factories import TINY_SCENE, random_scanset

from lesscli.io.scans import save_scans

LESS = str(Path(sys.executable).parent / "less")
ON_LINUX = os.path.isdir("/proc")


def _children(pid: int) -> list[str]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as fh:
            return fh.read().split()
    except OSError:
        return []


def _long_scene(folder: Path) -> Path:
    """Sixteen scans of 300 pokes: a parallel run of tens of seconds, interrupted long before its end."""
    path = folder / "long.toml"
    path.write_text(TINY_SCENE.replace("orientations = [0, 4]", "orientations = [0, 1, 2, 3, 4, 5, 6, 7]")
                    .replace("n_traj = 3", "n_traj = 300"))
    return path


def interrupt_simulate(folder: Path, delay_s: float) -> tuple[int, float, str]:
    """Start ``simulate --jobs 2`` in its own process group, wait until its workers run (plus ``delay_s``),
    send SIGINT to the whole group as a terminal's Ctrl-C does; (exit status, seconds to exit, stderr)."""
    proc = popen_interruptible([LESS, "simulate", "long.toml", "-o", "out.npz", "--jobs", "2"], cwd=folder,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(_children(proc.pid)) < 2 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.02)
        time.sleep(delay_s)
        start = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        _out, err = proc.communicate(timeout=30)
        return proc.returncode, time.monotonic() - start, err.decode()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _check_interrupted(folder: Path, code: int, seconds: float, err: str) -> None:
    assert code == 130 and seconds < 5.0, (code, seconds, err)
    assert err.strip().splitlines()[-1] == "less: interrupted" and "Traceback" not in err, err
    assert sorted(os.listdir(folder)) == ["long.toml"]           # no output, no temporary file, no lock


@pytest.mark.skipif(not ON_LINUX, reason="reads /proc to see the workers start")
def test_ctrl_c_of_a_parallel_simulate_exits_130_at_once(tmp_path):
    _long_scene(tmp_path)
    _check_interrupted(tmp_path, *interrupt_simulate(tmp_path, 0.3))


@pytest.mark.slow
@pytest.mark.skipif(not ON_LINUX, reason="reads /proc to see the workers start")
def test_ctrl_c_of_a_parallel_simulate_twenty_times_in_a_row(tmp_path):
    _long_scene(tmp_path)
    rng = random.Random(0)
    for _ in range(20):
        _check_interrupted(tmp_path, *interrupt_simulate(tmp_path, rng.uniform(0.0, 1.5)))


# ---------------------------------------------------------------------------------------------- full disk

def _mount_prefix() -> list[str] | None:
    """How to run a command in a private mount namespace (the tmpfs vanishes with it): ``unshare -m`` as
    root, ``unshare -rm`` (a user namespace) otherwise; None where neither works."""
    unshare = shutil.which("unshare")
    if not unshare:
        return None
    for prefix in ([unshare, "-m"], [unshare, "-rm"]) if os.geteuid() == 0 else ([unshare, "-rm"],):
        probe = subprocess.run([*prefix, "sh", "-c",
                                'd=$(mktemp -d) && mount -t tmpfs -o size=64k tmpfs "$d"'],
                               capture_output=True, timeout=30, check=False)
        if probe.returncode == 0:
            return prefix
    return None


PREFIX = _mount_prefix() if ON_LINUX else None


def on_small_disk(folder: Path, size_kib: int,
                  args: list[str]) -> tuple[subprocess.CompletedProcess, list[str]]:
    """Run ``less ARGS`` in ``folder`` with ``folder/disk`` a fresh tmpfs of ``size_kib`` KiB; the command's
    result and what it left on that disk (listed before the disk goes)."""
    disk = folder / "disk"
    disk.mkdir()
    script = (f"mount -t tmpfs -o size={size_kib}k tmpfs {shlex.quote(str(disk))} || exit 99; "
              f"{shlex.join([LESS, *map(str, args)])}; rc=$?; ls -A {shlex.quote(str(disk))} > disk.txt; "
              "exit $rc")
    proc = subprocess.run([*PREFIX, "sh", "-c", script], cwd=folder, capture_output=True, text=True,
                          timeout=600, check=False)
    assert proc.returncode != 99, proc.stderr
    return proc, (folder / "disk.txt").read_text().split()


needs_mount = pytest.mark.skipif(PREFIX is None,
                                 reason="cannot mount a tmpfs here (neither as root nor in a user "
                                                        "namespace: unshare -rm), so no small disk to fill")


def _one_error_line(proc, name: str) -> str:
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("less: error: ") and name in lines[0] and "Traceback" not in proc.stderr
    return lines[0]


@needs_mount
def test_a_full_disk_under_simulate_is_one_line_naming_the_file_and_nothing_left(tmp_path):
    (tmp_path / "tiny.toml").write_text(TINY_SCENE)
    proc, left = on_small_disk(tmp_path, 16, ["-q", "simulate", "tiny.toml", "-o", "disk/raw.npz"])
    line = _one_error_line(proc, "disk/raw.npz")
    assert "No space left on device" in line and left == []


@needs_mount
def test_a_full_disk_under_pretrain_leaves_neither_checkpoint_nor_log(tmp_path):
    save_scans(str(tmp_path / "s.npz"), random_scanset())
    proc, left = on_small_disk(tmp_path, 24, ["-q", "pretrain", "s.npz", "-o", "disk/rep.pt", "--epochs", "3",
                                              "--dim", "64"])
    line = _one_error_line(proc, "disk/rep")
    assert "No space left on device" in line and "PytorchStreamWriter" not in line and left == []


@needs_mount
def test_mri_label_writes_its_labels_only_with_its_figure(tmp_path):
    """The labels fit (on the test's own disk) but the --plot figure does not (a full tmpfs): neither
    appears."""
    made = subprocess.run([LESS, "mri-label", "--synth", "St12C13", "-o", "scan.nii.gz", "--spacing-mm",
                           "0.8,0.8,0.8"], cwd=tmp_path, capture_output=True, timeout=600, check=False)
    assert made.returncode == 0, made.stderr
    proc, left = on_small_disk(tmp_path, 8,
                               ["-q", "mri-label", "scan.nii.gz", "-o", "labels.nii.gz", "--plot",
                                             "disk/qc.png"])
    _one_error_line(proc, "disk/qc.png")
    assert left == [] and not (tmp_path / "labels.nii.gz").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["disk", "disk.txt", "scan.nii.gz"]


@needs_mount
def test_image_predict_writes_its_prediction_only_with_its_nifti_folder(tmp_path):
    from imaging_factory import save_tiny_imager

    save_tiny_imager(str(tmp_path / "im.pt"))
    save_scans(str(tmp_path / "s.npz"), random_scanset(n_scans=2, traj_per_scan=2, max_len=6, seed=1))
    proc, left = on_small_disk(tmp_path, 8, ["-q", "image", "predict", "im.pt", "s.npz", "-o", "p.npz",
                                             "--nifti", "disk/nii"])
    _one_error_line(proc, "disk/nii")
    assert left == [] and not (tmp_path / "p.npz").exists()


# ---------------------------------------------------------------------------------------------- lost folder,
# two writers

def _start_pretrain(folder: Path, output: str, epochs: int = 400) -> subprocess.Popen:
    return popen_interruptible([LESS, "-q", "pretrain", "s.npz", "-o", output, "--epochs", str(epochs),
                                "--dim", "8"], cwd=folder, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)


def _wait_for(path: Path, proc: subprocess.Popen, timeout_s: float = 120) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)


def test_an_output_folder_removed_mid_run_is_one_line_and_nothing_is_recreated(tmp_path):
    save_scans(str(tmp_path / "s.npz"), random_scanset())
    (tmp_path / "out").mkdir()
    proc = _start_pretrain(tmp_path, "out/rep.pt")
    try:
        _wait_for(tmp_path / "out" / "rep.log.jsonl", proc)        # training: the first epoch is written
        while (tmp_path / "out").exists():                          # the run may add a file while it goes
            shutil.rmtree(tmp_path / "out", ignore_errors=True)
        _out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    lines = err.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1 and "out/rep." in lines[0], err
    assert (("No such file or directory" in lines[0] or "does not exist" in lines[0])
            and "Traceback" not in err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.npz"]


def test_a_second_writer_of_one_output_refuses_at_its_start(tmp_path):
    save_scans(str(tmp_path / "s.npz"), random_scanset())
    first = _start_pretrain(tmp_path, "rep.pt")
    try:
        _wait_for(tmp_path / "rep.pt.lock", first)
        t0 = time.monotonic()
        second = subprocess.run([LESS, "pretrain", "s.npz", "-o", "rep.pt", "--epochs", "1", "--dim", "8"],
                                cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False)
        assert time.monotonic() - t0 < 60
        lines = second.stderr.strip().splitlines()
        assert second.returncode == 1 and len(lines) == 1, second.stderr
        assert lines[0] == (f"less: error: rep.pt: another less run (process {first.pid}) is writing it "
                            "(lock rep.pt.lock); wait for it to end or choose another output")
        assert first.poll() is None                                  # the first run goes on
        other = subprocess.run([LESS, "-q", "pretrain", "s.npz", "-o", "other.pt", "--epochs", "1", "--dim",
                                "8"],
                               cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False)
        assert other.returncode == 0, other.stderr                   # another output is free
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=60)
    finally:
        first.kill()
    assert first.returncode == 130 and not (tmp_path / "rep.pt.lock").exists()


def test_a_lock_left_by_a_killed_run_does_not_block_the_next(tmp_path):
    save_scans(str(tmp_path / "s.npz"), random_scanset())
    first = _start_pretrain(tmp_path, "rep.pt")
    try:
        _wait_for(tmp_path / "rep.pt.lock", first)
        first.send_signal(signal.SIGKILL)                            # no chance to clean up
        first.wait(timeout=60)
    finally:
        first.kill()
    assert (tmp_path / "rep.pt.lock").exists()
    again = subprocess.run([LESS, "-q", "pretrain", "s.npz", "-o", "rep.pt", "--epochs", "1", "--dim", "8"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False)
    assert again.returncode == 0, again.stderr
    assert not (tmp_path / "rep.pt.lock").exists() and (tmp_path / "rep.pt").exists()
