"""The CLI contract (DESIGN.md section 3), checked on the installed console script in subprocesses."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import popen_interruptible
from factories import random_scanset

from lesscli.cli.main import main
from lesscli.cli.registry import COMMANDS
from lesscli.io.atomic import atomic_path
from lesscli.io.scans import save_scans

BIN = Path(sys.executable).parent
LESS = str(BIN / "less")
HEAVY = ("torch", "cv2", "trimesh", "skimage", "dynamixel_sdk")

_PROBE = """
import contextlib, io, json, sys
from lesscli.cli.main import main
results = []
for args in json.loads(sys.argv[1]):
    out, err, code = io.StringIO(), io.StringIO(), 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(args)
        except SystemExit as exc:
            code = exc.code
    results.append({"args": args, "code": code, "help": out.getvalue(), "error": err.getvalue(),
                    "heavy": sorted(m for m in {HEAVY} if m in sys.modules)})
print(json.dumps(results))
""".replace("{HEAVY}", repr(HEAVY))


def _probe(*calls: list[str]) -> list[dict]:
    """Run ``main(args)`` for each call in one fresh interpreter; heavy modules seen after each call."""
    proc = subprocess.run([sys.executable, "-c", _PROBE, json.dumps(list(calls))], capture_output=True,
                          timeout=300, check=True)
    return json.loads(proc.stdout.decode().splitlines()[-1])


def test_help_lists_every_command_and_loads_nothing_heavy():
    (result,) = _probe(["--help"])
    assert result["code"] == 0 and result["heavy"] == []
    listed = result["help"].split("Commands:")[1]
    for name in COMMANDS:
        assert f"  {name} " in listed or f"  {name}\n" in listed, name


def test_every_subcommand_help_loads_nothing_heavy():
    results = _probe(*([name, "--help"] for name in sorted(COMMANDS)))
    problems = [(r["args"][0], r["code"], r["heavy"], r["error"].strip()) for r in results
                if r["code"] != 0 or r["heavy"] or "Usage:" not in r["help"]]
    assert problems == []


def test_exit_codes_0_1_2(run_less, scanset_file):
    assert run_less("info", scanset_file).returncode == 0
    missing = run_less("info", "missing.npz")
    assert missing.returncode == 1 and missing.stderr.decode() == "less: error: missing.npz: no such file\n"
    assert run_less("subsample", scanset_file).returncode == 2  # -o is required
    assert run_less("split", scanset_file, "--by", "colour", "-o", "x").returncode == 2
    assert run_less("info", scanset_file, "--format", "yaml").returncode == 2


def test_traceback_only_with_verbose(run_less):
    quiet = run_less("info", "missing.npz").stderr.decode()
    loud = run_less("-v", "info", "missing.npz").stderr.decode()
    assert "Traceback" not in quiet and len(quiet.splitlines()) == 1
    assert "Traceback" in loud and "missing.npz: no such file" in loud


def _start(args, **kwargs):
    """Start ``less ARGS``, Ctrl-C reaching it as from a terminal."""
    return popen_interruptible([LESS, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kwargs)


def _wait_until_loaded(pid: int, library: str = "_multiarray_umath", timeout_s: float = 120.0) -> None:
    """Block until the child has imported numpy (then it is about to read its input)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with open(f"/proc/{pid}/maps") as fh:
            if library in fh.read():
                time.sleep(0.5)
                return
        time.sleep(0.05)
    raise AssertionError("child never got ready")


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc to see when the child is ready")
def test_ctrl_c_exits_130(tmp_path):
    proc = _start(["info", "-"], stdin=subprocess.PIPE, cwd=tmp_path)
    try:
        proc.stdin.write(b"PK")  # a stdin that never ends: the command blocks reading it
        proc.stdin.flush()
        _wait_until_loaded(proc.pid)
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert b"interrupted" in err and b"Traceback" not in err


def test_ctrl_c_wrapped_by_an_import_still_exits_130(monkeypatch, capsys, scanset_file):
    """A Ctrl-C during a class body's ``__set_name__`` (torch's import) comes back as a RuntimeError
    whose cause is the KeyboardInterrupt: still an interrupt, not an error."""
    from lesscli.data import describe

    def interrupted_import(*_args, **_kwargs):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise RuntimeError("Error calling __set_name__ on 'Field' instance") from exc

    monkeypatch.setattr(describe, "describe_file", interrupted_import)
    with pytest.raises(SystemExit) as stop:
        main(["info", str(scanset_file)])
    assert stop.value.code == 130
    assert capsys.readouterr().err == "less: interrupted\n"


def test_closed_pipe_is_not_an_error(tmp_path):
    save_scans(str(tmp_path / "big.npz"), random_scanset(n_scans=4, traj_per_scan=20, max_len=40))
    assert (tmp_path / "big.npz").stat().st_size > 4 * 65536  # more than a pipe buffer
    proc = _start(["subsample", "big.npz", "-o", "-"], cwd=tmp_path)
    head = proc.stdout.read(10)
    proc.stdout.close()
    err = proc.stderr.read()
    proc.wait(timeout=120)
    assert head.startswith(b"PK") and proc.returncode == 0 and err == b""


def test_failed_command_leaves_no_partial_file_and_keeps_the_old_one(run_less, tmp_path, scanset_file):
    (tmp_path / "out.npz").write_bytes(b"old")
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 not really")
    proc = run_less("subsample", "bad.npz", "-o", "out.npz")
    assert proc.returncode == 1 and (tmp_path / "out.npz").read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["bad.npz", "out.npz", "scans.npz"]
    with pytest.raises(RuntimeError), atomic_path(str(tmp_path / "new.npz"), ".npz") as tmp:
        Path(tmp).write_bytes(b"half")
        raise RuntimeError("boom")
    assert not (tmp_path / "new.npz").exists() and len(os.listdir(tmp_path)) == 3


def test_binary_output_refused_on_a_terminal(tmp_path, scanset_file):
    import pty

    main_fd, child_fd = pty.openpty()
    try:
        proc = subprocess.run([LESS, "subsample", str(scanset_file), "-o", "-"], check=False, stdout=child_fd,
                              stderr=subprocess.PIPE, timeout=120, cwd=tmp_path)
    finally:
        os.close(child_fd)
        os.close(main_fd)
    assert proc.returncode == 1 and b"refusing to write binary output to a terminal" in proc.stderr


# ---------------------------------------------------------------------------------------------- pager safety

def _path_without_system_less() -> str:
    return str(BIN)


def test_piped_stdin_goes_to_the_system_pager(run_less, tmp_path):
    assert os.path.exists("/usr/bin/less")
    proc = subprocess.run(f"printf 'x\\n' | {LESS}", shell=True, capture_output=True, timeout=60, check=False,
                          env={**os.environ, "PATH": f"{BIN}{os.pathsep}/usr/bin{os.pathsep}/bin"})
    assert proc.returncode == 0 and proc.stdout == b"x\n"
    (tmp_path / "notes.txt").write_text("line one\nline two\n")
    shown = run_less("notes.txt", env={"PATH": f"{BIN}{os.pathsep}/usr/bin{os.pathsep}/bin"})
    assert shown.returncode == 0 and shown.stdout == b"line one\nline two\n"
    flagged = run_less("-R", input=b"a\nb\n", env={"PATH": f"{BIN}{os.pathsep}/usr/bin"})
    assert flagged.returncode == 0 and flagged.stdout == b"a\nb\n"


def test_hand_over_passes_arguments_to_the_next_less_on_path(run_less, tmp_path):
    fake = tmp_path / "fakebin"
    fake.mkdir()
    (fake / "less").write_text("#!/bin/sh\necho \"system pager: $*\"\n")
    (fake / "less").chmod(0o755)
    proc = run_less("-R", "+G", "file.txt", env={"PATH": f"{BIN}{os.pathsep}{fake}"})
    assert proc.stdout == b"system pager: -R +G file.txt\n"
    proc = run_less(input=b"x\n", env={"PATH": f"{BIN}{os.pathsep}{fake}"})
    assert proc.stdout == b"system pager: \n"


def test_without_a_system_pager_input_is_copied(run_less, tmp_path):
    env = {"PATH": _path_without_system_less()}
    assert run_less(input=b"x\n", env=env).stdout == b"x\n"
    (tmp_path / "notes.txt").write_bytes(b"hello\n")
    assert run_less("notes.txt", env=env).stdout == b"hello\n"
    missing = run_less("nothere.txt", env=env)
    assert missing.returncode == 2 and b"'nothere.txt' (and no such file)" in missing.stderr


@pytest.mark.parametrize("script, args, hint", [
    ("less", ["simulat", "x"], "Did you mean 'simulate'?"),
    ("lesscli", ["imgae", "predict"], "Did you mean 'image'?"),
    ("less", ["-q", "metrcs"], "Did you mean 'metrics'?"),
])
def test_a_typo_is_a_usage_error_not_a_pager_call(tmp_path, script, args, hint):
    fake = tmp_path / "fakebin"
    fake.mkdir()
    (fake / "less").write_text("#!/bin/sh\necho paged\n")
    (fake / "less").chmod(0o755)
    proc = subprocess.run([str(BIN / script), *args], capture_output=True, timeout=60, check=False,
                          cwd=tmp_path, env={**os.environ, "PATH": f"{BIN}{os.pathsep}{fake}"})
    assert proc.returncode == 2 and proc.stdout == b""
    assert hint in proc.stderr.decode()


def test_lesscli_never_pages(tmp_path):
    fake = tmp_path / "fakebin"
    fake.mkdir()
    (fake / "less").write_text("#!/bin/sh\necho paged\n")
    (fake / "less").chmod(0o755)
    (tmp_path / "notes.txt").write_text("hello\n")
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{fake}"}
    piped = subprocess.run([str(BIN / "lesscli")], input=b"x\n", capture_output=True, timeout=60, check=False,
                           env=env, cwd=tmp_path)
    assert b"paged" not in piped.stdout and b"Usage: less" in piped.stdout + piped.stderr
    named = subprocess.run([str(BIN / "lesscli"), "notes.txt"], capture_output=True, timeout=60, check=False,
                           env=env, cwd=tmp_path)
    assert named.returncode == 2 and b"paged" not in named.stdout
