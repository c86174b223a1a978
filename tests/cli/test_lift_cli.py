"""``less lift`` end to end: in-process CLI against the pty emulator, and real subprocess pipes."""

import json
import logging
import signal
import subprocess
import sys

import pytest

from lesscli.cli.main import main
from lesscli.hardware.bus import DynamixelBus
from lesscli.hardware.config import load_config
from lesscli.hardware.emulator import PtyEmulator, ServoEmulator, lift_servos
from lesscli.hardware.servo_model import Fault

# latency_ms and retries: the emulator may answer late on a loaded machine
FAST_TOML = ("[bus]\nlatency_ms = 150.0\nretries = 2\n"
             "[timing]\npoll_s = 0.001\nstall_s = 0.05\ntimeout_margin_s = 5.0\n")
RECORDER = "import sys\nwith open(sys.argv[1], 'a') as fh:\n    fh.write(sys.argv[2] + '\\n')\n"


@pytest.fixture
def cfg_path(tmp_path):
    path = tmp_path / "lift.toml"
    path.write_text(FAST_TOML)
    return path


@pytest.fixture
def emu(cfg_path):
    emulator = ServoEmulator(lift_servos(load_config(str(cfg_path))), time_scale=1000.0)
    with PtyEmulator(emulator) as pty:
        emulator.port = pty.port
        yield emulator


@pytest.fixture
def less(capsys, emu, cfg_path):
    """Run ``less lift --port <emulator> --config <fast> ARGS`` in-process: (exit code, records, stderr)."""

    def run(*args, port=None):
        logging.getLogger("less").handlers.clear()  # log to this test's captured stderr
        try:
            main(["lift", "--port", str(port or emu.port), "--config", str(cfg_path), *map(str, args)])
            code = 0
        except SystemExit as exc:
            code = exc.code
        out, err = capsys.readouterr()
        return code, [json.loads(line) for line in out.splitlines()], err

    return run


def torque_off(emu):
    with emu.lock:
        return all(s.get("Torque_Enable") == 0 for s in emu.servos.values())


def test_status_is_one_json_record(less):
    code, records, err = less("status")
    assert code == 0, err
    (record,) = records
    assert record["event"] == "status" and record["homed"] is False and record["height_mm"] is None
    assert set(record) >= {"time_s", "height_mm", "rotator_deg", "orientation", "moving", "torque", "errors"}


@pytest.mark.parametrize("before, after", [(None, "markdown"), ("markdown", None), ("jsonl", "markdown")])
def test_format_is_taken_after_the_subcommand_too(before, after, emu, cfg_path, capsys):
    """``less lift status --format markdown``; given on both sides, the subcommand's wins."""
    logging.getLogger("less").handlers.clear()
    main(["lift", "--port", emu.port, "--config", str(cfg_path), *(["--format", before] if before else []),
          "status", *(["--format", after] if after else [])])
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3 and lines[0].startswith("|") and "height_mm" in lines[0], lines


def test_missing_port_is_a_one_line_error(less, tmp_path):
    code, _, err = less("status", port=tmp_path / "ttyUSB9")
    assert code == 1
    assert err.strip().splitlines() == [(f"less: error: {tmp_path / 'ttyUSB9'}: cannot open serial port: "
                                        "No such file or directory")]


def test_busy_port_is_a_one_line_error(less, emu):
    with DynamixelBus(emu.port):
        code, _, err = less("status")
    assert code == 1 and err.strip() == f"less: error: {emu.port}: port is busy (another program has it open)"


def test_missing_servo_id_names_it(less, emu):
    code, _, err = less("--ids", "1,9", "status")
    assert code == 1 and f"{emu.port}: servo 9: PING: no reply" in err and "Traceback" not in err


def test_moves_need_homing_and_limits(less, emu):
    code, _, err = less("raise")
    assert code == 1 and "not homed since the last power-up" in err
    assert less("home")[0] == 0
    code, _, err = less("move", "--height-mm", 500)
    assert code == 1 and "height 500 mm is outside the lift limits [32, 100] mm" in err
    assert less("rotate", 9)[0] == 2
    assert torque_off(emu)


def test_cycle_visits_the_8_orientations_in_order_and_runs_exec(less, emu, tmp_path):
    script, log = tmp_path / "record.py", tmp_path / "visited.txt"
    script.write_text(RECORDER)
    assert less("home")[0] == 0
    code, records, err = less("cycle", "--orientations", "0-7", "--exec", f"{sys.executable} {script} {log} "
                              "{orientation}")
    assert code == 0, err
    assert log.read_text().split() == [str(k) for k in range(8)]
    assert [g[2] for g in emu.servos[2].goals] == [512 * k for k in range(8)]
    assert [r["target"] for r in records if r["event"] == "orientation"] == list(range(8))
    assert all(r["orientation"] == r["target"] and r["height_mm"] == pytest.approx(95.0, abs=0.05)
               for r in records if r["event"] == "orientation")
    assert torque_off(emu)


def test_cycle_stops_cleanly_when_exec_fails(less, emu, tmp_path):
    assert less("home")[0] == 0
    failing = (f"{sys.executable} -c \"import sys; sys.exit(3 if int(sys.argv[1]) == 2 else 0)\" "
               f"{{orientation}}")
    code, _, err = less("cycle", "--exec", failing)
    assert code == 1 and "cycle stopped at orientation 2: --exec command exited with 3" in err
    assert [g[2] for g in emu.servos[2].goals] == [0, 512, 1024]
    assert torque_off(emu)


@pytest.mark.parametrize("fault, words", [("overload", "overload"), ("stall", "stall"),
                                          ("power-cycle", "power cycle"), ("no-reply", "no reply"),
                                          ("bad-crc", "CRC mismatch")])
def test_faults_exit_1_naming_the_fault_with_torque_dropped(less, emu, fault, words):
    assert less("home")[0] == 0
    assert less("rotate", 4)[0] == 0
    emu.arm(1, Fault(fault, goal=1))
    code, _, err = less("raise")
    assert code == 1 and words in err and len(err.strip().splitlines()) <= 3, err
    assert torque_off(emu)


def test_torque_off_command(less, emu):
    with emu.lock:
        emu.servos[1].set("Torque_Enable", 1)
    code, records, _ = less("torque-off")
    assert code == 0 and records[0]["failures"] == [] and torque_off(emu)


def test_cli_module_does_not_import_the_sdk():
    code = "import sys, lesscli.cli.lift, lesscli.hardware.lift; print('dynamixel_sdk' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_emulate_in_background_with_real_pipes(run_less, tmp_path, cfg_path):
    from conftest import BIN

    link, log = tmp_path / "lift0", tmp_path / "emu.jsonl"
    emulator = subprocess.Popen([str(BIN / "less"), "lift", "--config", str(cfg_path), "emulate", "--link",
                                 str(link), "--time-scale", "500", "--log", str(log), "--fault",
                                 "overload:2:9"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert emulator.stdout.readline().strip() == str(link)
        base = ["lift", "--port", link, "--config", cfg_path]
        run_less(*base, "home", check=True)
        out = run_less(*base, "cycle", "--orientations", "0-7", "--exec", "echo palpate {orientation}",
                       check=True)
        visits = [json.loads(line)["target"] for line in out.stdout.splitlines()
                  if json.loads(line)["event"] == "orientation"]
        assert visits == list(range(8)) and b"palpate 7" in out.stderr
        failed = run_less(*base, "lower")  # ninth rotator goal would overload; this only moves the lift
        assert failed.returncode == 0
        broken = run_less(*base, "rotate", 3)
        assert broken.returncode == 1 and b"overload" in broken.stderr
    finally:
        emulator.terminate()
        assert emulator.wait(timeout=10) == 0
    assert not link.exists()
    goals = [json.loads(line) for line in log.read_text().splitlines()]
    assert ([g["goal"] for g in goals if g["event"] == "goal" and g["id"] == 2]
            == [512 * k for k in range(8)] + [1536])


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupt_mid_move_drops_torque(cfg_path, sig, code):
    from conftest import BIN, popen_interruptible

    emulator = ServoEmulator(lift_servos(load_config(str(cfg_path))), time_scale=1.0)  # homing takes seconds
    with PtyEmulator(emulator) as pty:
        proc = popen_interruptible([str(BIN / "less"), "lift", "--port", pty.port, "--config", str(cfg_path),
                                    "home"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            first = json.loads(proc.stdout.readline())
            assert first["event"] == "homing" and first["torque"][0] is True
            proc.send_signal(sig)
            assert proc.wait(timeout=30) == code
        finally:
            proc.kill()
        assert torque_off(emulator)
        assert emulator.servos[1].goals == []  # homing runs in velocity mode: no position goal was sent
