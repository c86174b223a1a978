"""The thread policy (pure rules, table-tested; fixed by the cores unless the work is latency-bound or
``--threads auto`` asks, then by the load average too), the user's ``OMP_NUM_THREADS``, ``--threads``
reaching torch, ``bench stream --load`` and ``--realtime``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import click
import pytest
import torch
from click.testing import CliRunner
from factories import random_scanset
from imaging_factory import save_tiny_imager

from lesscli.bench.timing import SPIN, busy_processes
from lesscli.cli.bench_stream import load_levels
from lesscli.cli.main import cli
from lesscli.infer.stream import StreamingImager
from lesscli.io.scans import save_scans
from lesscli.threads import (
    POOL_ENV_VARS,
    apply_threads,
    free_cores,
    load_average,
    parse_threads,
    resolve_threads,
    user_threads,
)

BIN = Path(sys.executable).parent


@pytest.mark.parametrize("cores, load, expected", [
    (2, 0.0, 2), (2, 0.4, 2), (2, 0.6, 1), (2, 1.0, 1), (2, 5.0, 1), (8, 2.4, 6), (8, 2.5, 5), (1, 0.0, 1),
])
def test_free_cores_subtract_the_rounded_load_and_keep_one(cores, load, expected):
    assert free_cores(cores, load) == expected


def test_the_load_average_is_finite_and_never_negative():
    assert 0.0 <= load_average() < float("inf")


@pytest.mark.parametrize("work, cores, override, user, jobs, load, expected", [
    ("throughput", 2, None, None, 1, 0.0, 2),      # training on a quiet machine: every core
    ("throughput", 8, None, None, 1, 7.0, 8),      # ... beside a busy one: still every core (same bits)
    ("throughput", 8, None, None, 2, 7.0, 4),      # workers split the cores, not the free ones
    ("throughput", 8, None, None, 3, 0.0, 2),      # ... rounding down
    ("throughput", 2, None, None, 4, 0.0, 1),      # more workers than cores: one each
    ("throughput", 8, None, 3, 1, 7.0, 3),         # the user's OMP_NUM_THREADS
    ("throughput", 8, 5, 3, 1, 7.0, 5),            # --threads wins over it
    ("throughput", 2, 3, None, 1, 0.0, 3),         # ... even above the cores
    ("throughput", 8, "auto", None, 1, 3.0, 5),    # --threads auto: the free cores
    ("throughput", 8, "auto", None, 2, 2.4, 3),    # ... split between workers (8 - 2 = 6 free)
    ("throughput", 8, "auto", 2, 1, 3.0, 5),       # ... asked for, so the user's count does not cap it
    ("throughput", 2, "auto", None, 1, 5.0, 1),    # overloaded: still one
    ("latency", 8, None, None, 1, 0.0, 2),         # stream / guide: two threads when two cores are free
    ("latency", 2, None, None, 1, 0.4, 2),
    ("latency", 2, None, None, 1, 0.6, 1),         # ... one when a busy neighbour takes a core
    ("latency", 8, None, None, 8, 0.0, 1),         # ... or each of the workers has one
    ("latency", 8, None, 1, 1, 0.0, 1),            # ... at most the user's OMP_NUM_THREADS
    ("latency", 8, 3, None, 1, 7.0, 3),            # --threads wins
    ("latency", 8, "auto", None, 1, 1.0, 7),       # --threads auto: all the free cores
])
def test_thread_policy_table(work, cores, override, user, jobs, load, expected):
    n, why = resolve_threads(work, cores, override, user, jobs, load)
    assert n == expected, why


@pytest.mark.parametrize("text, levels", [("0", [0]), ("2", [0, 2]), ("0,1,2", [0, 1, 2]), ("1,", [1])])
def test_load_levels(text, levels):
    assert load_levels(text) == levels


@pytest.mark.parametrize("text", ["-1", "x", ""])
def test_load_levels_reject_bad_text(text):
    with pytest.raises(click.BadParameter):
        load_levels(text)


def _spinning_children() -> list[int]:
    """Pids of this process's children running the busy loop."""
    found = []
    for entry in os.listdir("/proc"):
        try:
            with open(f"/proc/{entry}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmd = f.read()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == os.getpid() and SPIN.encode() in cmd:
            found.append(int(entry))
    return found


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads /proc")
@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_busy_processes_spin_and_are_gone_after_an_error(error):
    with pytest.raises(error), busy_processes(2, settle_s=0.0) as procs:
        assert sorted(_spinning_children()) == sorted(p.pid for p in procs)
        raise error
    assert all(p.returncode is not None for p in procs) and _spinning_children() == []


@pytest.fixture
def keep_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


@pytest.fixture
def tiny_files(tmp_path):
    """A tiny imaging checkpoint and a one-scan set in tmp_path (im.pt, s.npz)."""
    save_tiny_imager(str(tmp_path / "im.pt"))
    save_scans(str(tmp_path / "s.npz"), random_scanset(n_scans=1, traj_per_scan=2, max_len=4, seed=1))
    return tmp_path


def test_threads_option_reaches_torch_inside_stream(tiny_files, monkeypatch, keep_threads):
    tmp_path = tiny_files
    seen, push = [], StreamingImager.push
    monkeypatch.setattr(StreamingImager, "push", lambda self,
                        *a: seen.append(torch.get_num_threads()) or push(self, *a))
    for threads in (3, 1):
        seen.clear()
        result = CliRunner().invoke(cli, ["stream", str(tmp_path / "im.pt"), str(tmp_path / "s.npz"),
                                          "--threads", str(threads)])
        assert result.exit_code == 0, result.output
        assert seen and set(seen) == {threads}


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads /proc")
def test_bench_stream_load_reports_quiet_and_loaded_rows_and_leaves_no_busy_process(keep_threads):
    result = CliRunner().invoke(cli, ["bench", "stream", "--load", "1", "--steps", "50", "--updates", "5",
                                      "--full-repeats", "1", "--dim", "2", "--width", "8", "--format",
                                      "jsonl"])
    assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in result.stdout.splitlines() if line.strip()]
    assert [(r["load"], r["steps"]) for r in rows] == [(0, 50), (1, 50)]
    assert all(0 < r["incremental_median_ms"] <= r["incremental_p99_ms"] and r["threads"] >= 1 for r in rows)
    assert _spinning_children() == []


def test_image_predict_records_the_thread_count(tiny_files, keep_threads):
    tmp_path = tiny_files
    result = CliRunner().invoke(cli, ["image", "predict", str(tmp_path / "im.pt"), str(tmp_path / "s.npz"),
                                      "-o", str(tmp_path / "p.npz"), "--threads", "3", "--format", "jsonl"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout.splitlines()[-1])["threads"] == 3 == torch.get_num_threads()


def test_apply_threads_sets_torch_and_takes_the_callers_load(monkeypatch):
    """--threads fixes the count; latency-bound work beside a load the caller knows (busy processes it
    just started) takes one thread, on a quiet machine of two cores or more two."""
    for name in POOL_ENV_VARS:                      # restored after the test
        monkeypatch.setenv(name, os.environ.get(name, ""))
    monkeypatch.delenv("OMP_NUM_THREADS")
    before = torch.get_num_threads()
    try:
        assert apply_threads("latency", override=3) == 3 == torch.get_num_threads()
        assert apply_threads("latency", load=float(os.cpu_count())) == 1 == torch.get_num_threads()
        quiet = 2 if len(os.sched_getaffinity(0)) >= 2 else 1
        assert apply_threads("latency", load=0.0) == quiet == torch.get_num_threads()
    finally:
        torch.set_num_threads(before)


# --realtime: each case runs in a fresh interpreter, so the test process keeps its own policy. Whether
# this system lets a process take the FIFO policy is probed with the raw system call first; the
# command must then agree with it (take it, or refuse in one line).
_PROBE = "import os\nos.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))\n"
_SET = """
import os, sys, threading
from lesscli.errors import LessError
from lesscli.realtime import set_realtime
{before}
started = threading.Event()
worker = threading.Thread(target=lambda: (started.set(), threading.Event().wait(5)), daemon=True)
worker.start(); started.wait()                       # a thread that exists before the call
try:
    set_realtime()
except LessError as e:
    print("refused:", e); sys.exit(3)
later = threading.Thread(target=lambda: print("later", os.sched_getscheduler(0) == os.SCHED_FIFO))
later.start(); later.join()                          # a thread started after it
from lesscli.bench.timing import busy_processes
import time
with busy_processes(1) as procs:                     # it resets its policy as it starts
    deadline = time.monotonic() + 10
    while os.sched_getscheduler(procs[0].pid) != os.SCHED_OTHER and time.monotonic() < deadline:
        time.sleep(0.01)
    print("busy", os.sched_getscheduler(procs[0].pid) == os.SCHED_OTHER)
tids = os.listdir("/proc/self/task")
print("all", all(os.sched_getscheduler(int(t)) == os.SCHED_FIFO for t in tids), len(tids) >= 2)
"""
_NOT_PERMITTED = """
import os, resource
if os.geteuid() == 0:
    os.setgid(65534); os.setuid(65534)               # nobody: no capabilities
resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
"""


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True,
                          timeout=60)


@pytest.mark.skipif(not hasattr(os, "SCHED_FIFO"), reason="no real-time scheduling on this platform")
def test_realtime_takes_the_fifo_policy_where_the_system_permits_it_and_refuses_in_one_line_where_not():
    permitted = _python(_PROBE).returncode == 0
    out = _python(_SET.format(before=""))
    if permitted:
        assert out.returncode == 0, out.stderr
        # every thread, one started later too; the busy processes of the benchmarks stay ordinary
        assert out.stdout.split() == ["later", "True", "busy", "True", "all", "True", "True"]
    else:
        assert out.returncode == 3 and "may not take real-time priority 10" in out.stdout
    refused = _python(_SET.format(before=_NOT_PERMITTED))
    assert refused.returncode == 3, refused.stdout + refused.stderr
    assert refused.stdout.count("\n") == 1 and "ulimit -r" in refused.stdout


@pytest.mark.skipif(not hasattr(os, "SCHED_FIFO"), reason="no real-time scheduling on this platform")
@pytest.mark.parametrize("command", ["bench", "stream"])
def test_realtime_commands_run_under_it_or_stop_with_one_line(command, tiny_files):
    args = {"bench": ["bench", "stream", "--steps", "50", "--updates", "3", "--full-repeats", "1", "--dim",
                      "2", "--width", "8", "--format", "jsonl"],
            "stream": ["stream", str(tiny_files / "im.pt"), str(tiny_files / "s.npz"), "--emit-every",
                       "2"]}[command]
    permitted = _python(_PROBE).returncode == 0
    out = subprocess.run([sys.executable, "-m", "lesscli", "-v", *args, "--realtime"], check=False,
                         capture_output=True, text=True, timeout=120)
    if permitted:
        assert out.returncode == 0, out.stderr
        rows = [json.loads(line) for line in out.stdout.splitlines() if line.strip()]
        assert rows and "scheduling: real-time FIFO, priority 10" in out.stderr
        assert command != "bench" or all(r["realtime"] is True for r in rows)
    else:
        assert out.returncode == 1 and out.stdout == ""
        assert out.stderr.strip().count("\n") == 0 and "--realtime" in out.stderr


@pytest.mark.parametrize("text, expected", [("3", 3), ("auto", "auto"), ("AUTO", "auto"), (None, None)])
def test_parse_threads(text, expected):
    assert parse_threads(text) == expected


@pytest.mark.parametrize("text", ["0", "-2", "x", "1.5"])
def test_parse_threads_refuses(text):
    with pytest.raises(ValueError):
        parse_threads(text)


def test_the_users_omp_num_threads_is_respected_and_left_alone(tiny_files):
    """Through the console script: OMP_NUM_THREADS=1 is the count (on any machine) and stays as it was;
    without it the count is the cores, and --threads auto is accepted."""
    env = {k: v for k, v in os.environ.items() if k not in POOL_ENV_VARS}
    args = [str(BIN / "less"), "-v", "image", "predict", "im.pt", "s.npz", "-o", "p.npz", "--format", "jsonl"]
    probe = "; import os; print('OMP', os.environ.get('OMP_NUM_THREADS'))"
    out = subprocess.run(args, cwd=tiny_files, env={**env, "OMP_NUM_THREADS": "1"}, capture_output=True,
                         text=True, timeout=300, check=True)
    assert (json.loads(out.stdout.splitlines()[-1])["threads"] == 1
            and "threads: 1 (OMP_NUM_THREADS)" in out.stderr)
    plain = subprocess.run(args, cwd=tiny_files, env=env, capture_output=True, text=True, timeout=300,
                           check=True)
    assert json.loads(plain.stdout.splitlines()[-1])["threads"] == len(os.sched_getaffinity(0))
    auto = subprocess.run([*args, "--threads", "auto"], cwd=tiny_files, env=env, capture_output=True,
                          text=True, timeout=300, check=True)
    assert "threads: " in auto.stderr and "--threads auto: cores" in auto.stderr
    bad = subprocess.run([*args, "--threads", "many"], cwd=tiny_files, env=env, capture_output=True,
                         text=True, timeout=300, check=False)
    assert bad.returncode == 2 and "'many' is not a whole number >= 1 nor 'auto'" in bad.stderr
    # the policy never writes the user's variable: a child started by the command sees what the user set
    code = ("import os, sys; os.environ['OMP_NUM_THREADS'] = '1'; from lesscli.threads import apply_threads, "
            "set_threads; apply_threads('throughput', torch_too=False); set_threads(5, torch_too=False)"
            + probe)
    assert subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                          check=True).stdout.split() == ["OMP", "1"]


def test_a_malformed_omp_num_threads_is_ignored_with_one_line(monkeypatch, caplog):
    monkeypatch.setenv("OMP_NUM_THREADS", "lots")
    with caplog.at_level("WARNING", logger="less"):
        assert user_threads() is None
    assert "OMP_NUM_THREADS='lots' is not a whole number >= 1; ignored" in caplog.text
