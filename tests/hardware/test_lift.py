"""ScissorLift over the real dynamixel_sdk talking to the pty emulator: homing, moves, faults, limits."""

import itertools
import math
import os
from contextlib import contextmanager

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lesscli.errors import DataError, LessError
from lesscli.hardware.bus import DynamixelBus
from lesscli.hardware.config import LiftConfig, ScissorGeometry, load_config
from lesscli.hardware.emulator import PtyEmulator, ServoEmulator, lift_servos
from lesscli.hardware.lift import LiftFault, ScissorLift
from lesscli.hardware.servo_model import Fault

# latency_ms and retries: the emulator thread may answer late on a loaded machine
FAST = {"poll_s": 0.001, "stall_s": 0.05, "timeout_margin_s": 5.0, "latency_ms": 150.0, "retries": 2}
TIME_SCALE = 1000.0


@contextmanager
def rig(config: LiftConfig | None = None, homed: bool = True):
    """(lift, emulator) with a fresh emulated lift; torque is dropped on exit like in the CLI."""
    config = config or load_config(None, **FAST)
    emulator = ServoEmulator(lift_servos(config), time_scale=TIME_SCALE)
    records = []
    with (PtyEmulator(emulator) as pty,
          DynamixelBus(pty.port, config.baud, config.retries, config.latency_ms) as bus,
          ScissorLift(bus, config, emit=records.append) as lift):
        lift.records = records
        if homed:
            lift.home()
        yield lift, emulator


def torque(emulator, servo_id):
    with emulator.lock:
        return emulator.servos[servo_id].get("Torque_Enable")


def lift_heights(emulator, config):
    """Heights (mm) of every Goal_Position the lift servo received, from its physical shaft ticks."""
    return [config.geometry.height_for_ticks(true) for _, _, _, true in emulator.servos[config.lift_id].goals]


# -- geometry and config ------------------------------------------------------------------------------
@pytest.mark.parametrize("direction", [1, -1])
def test_geometry_round_trip_and_monotonic(direction):
    g = ScissorGeometry(direction=direction)
    heights = [30.0, 35.0, 60.0, 95.0, 100.0]
    ticks = [g.ticks_for_height(h) for h in heights]
    assert ticks[0] == 0.0
    assert all(direction * (b - a) > 0 for a, b in itertools.pairwise(ticks))
    assert [g.height_for_ticks(t) for t in ticks] == pytest.approx(heights, abs=1e-9)


def test_geometry_hand_value():
    # L=100, 2 stages, offset 20, lead 2: feet 99.8749 mm apart at 30 mm, 91.6515 mm at 100 mm
    g = ScissorGeometry()
    expected_turns = (math.sqrt(100**2 - 5**2) - math.sqrt(100**2 - 40**2)) / 2.0
    assert g.turns_for_height(100.0) == pytest.approx(expected_turns)
    assert g.ticks_for_height(100.0) == pytest.approx(expected_turns * 4096)


def test_config_file_and_errors(tmp_path):
    path = tmp_path / "lift.toml"
    path.write_text("[bus]\nbaud = 1000000\n[lift]\nid = 3\n[limits]\nmax_height_mm = 90.0\n"
                    "raised_height_mm = 88.0\n[geometry]\ndirection = -1\n")
    config = load_config(str(path), rotator_id=4)
    assert (config.baud, config.lift_id, config.rotator_id, config.max_height_mm) == (1000000, 3, 4, 90.0)
    assert config.geometry.direction == -1
    path.write_text("[limits]\nmax_heigth_mm = 90\n")
    with pytest.raises(DataError, match=r"lift.toml: \[limits\] unknown key 'max_heigth_mm'"):
        load_config(str(path))
    path.write_text("[limits]\nraised_height_mm = 120.0\n")
    with pytest.raises(DataError, match="raised_height_mm <= max_height_mm"):
        load_config(str(path))
    path.write_text("[lift]\nid = 'one'\n")
    with pytest.raises(DataError, match="'lift_id' must be a number"):
        load_config(str(path))
    path.write_text("[rotator]\nzero_ticks = 600\n")
    with pytest.raises(DataError, match="zero_ticks must be in 0..511"):
        load_config(str(path))
    with pytest.raises(DataError, match="missing.toml: no such lift config"):
        load_config(str(tmp_path / "missing.toml"))


# -- behaviour over the emulator ----------------------------------------------------------------------
def test_home_then_raise_lower_and_rotate():
    with rig() as (lift, emu):
        cfg = lift.config
        assert lift.status()["height_mm"] == pytest.approx(cfg.lowered_height_mm, abs=0.05)
        lift.rotate(3)
        lift.raise_()
        status = lift.status()
        assert status["orientation"] == 3 and status["rotator_deg"] == pytest.approx(135.0)
        assert status["height_mm"] == pytest.approx(cfg.raised_height_mm, abs=0.05)
        lift.move_to_height(60.0)
        assert lift.status()["height_mm"] == pytest.approx(60.0, abs=0.05)
        assert {r["event"] for r in lift.records} >= {"homing", "homed", "move", "arrived"}
    assert torque(emu, 1) == 0 and torque(emu, 2) == 0


@pytest.mark.parametrize("direction", [1, -1])
def test_homing_zeroes_at_the_lower_stop(direction):
    config = load_config(None, **FAST)
    config = LiftConfig(**{**config.__dict__, "geometry": ScissorGeometry(direction=direction)})
    with rig(config) as (_lift, emu):
        servo = emu.servos[config.lift_id]
        expected = config.geometry.ticks_for_height(config.lowered_height_mm)
        assert servo.true_ticks == pytest.approx(expected, abs=config.tolerance_ticks)
        assert all(g[1] == 4 for g in servo.goals)  # homing itself writes no position goal


def test_limits_are_checked_before_any_command():
    with rig() as (lift, emu):
        before = len(emu.servos[1].goals)
        for height in (10.0, 31.9, 100.5, float("nan")):
            with pytest.raises(LessError, match="outside the lift limits"):
                lift.move_to_height(height)
        assert len(emu.servos[1].goals) == before


def test_rotation_needs_the_lift_lowered_and_raising_needs_alignment():
    with rig() as (lift, emu):
        lift.rotate(0)
        lift.raise_()
        with pytest.raises(LiftFault, match="run 'less lift lower' before rotating"):
            lift.rotate(1)
        lift.lower()
        lift.bus.write(2, "Torque_Enable", 0)
        with emu.lock:
            emu.servos[2].true_ticks += 200  # someone nudged the insert
        with pytest.raises(LiftFault, match="not at one of the 8 orientations"):
            lift.raise_()


def test_cycle_visits_orientations_in_order():
    seen = []
    with rig() as (lift, emu):
        lift.cycle(range(8), run=lambda k: seen.append((k, lift.status()["orientation"],
                                                        round(lift.status()["height_mm"]))))
        rot_goals = [g[2] for g in emu.servos[2].goals]
    assert seen == [(k, k, 95) for k in range(8)]
    assert rot_goals == [512 * k for k in range(8)]


@pytest.mark.parametrize("fault, servo_id, message", [
    ("overload", 1, "overload"), ("overheating", 1, "overheating"), ("stall", 1, "stall"),
    ("power-cycle", 1, "power cycle"), ("no-reply", 1, "no reply"), ("bad-crc", 1, "corrupted status packet"),
    ("overload", 2, "overload"), ("stall", 2, "stall"), ("power-cycle", 2, "power cycle"),
])
def test_every_fault_stops_the_lift_and_drops_torque(fault, servo_id, message):
    with pytest.raises(LessError, match=message) as exc, rig() as (lift, emu):
        lift.rotate(1)
        emu.arm(servo_id, Fault(fault, goal=1))  # fires during the next move of that servo
        lift.raise_() if servo_id == 1 else lift.rotate(5)
    if isinstance(exc.value, LiftFault):
        assert exc.value.fault.replace("-", " ") in message
    assert torque(emu, 1) == 0 and torque(emu, 2) == 0
    servo = emu.servos[servo_id]
    if fault not in ("no-reply", "bad-crc"):  # the shaft stopped short of the commanded goal
        assert abs(servo.true_ticks - servo.goals[-1][3]) > 100


def test_power_cycle_forces_rehoming_before_the_next_move():
    with rig() as (lift, emu):
        lift.rotate(0)
        lift.raise_()
        emu.inject("power-cycle", 1)
        with pytest.raises(LiftFault, match="not homed since the last power-up.*power cycle"):
            lift.lower()
        moves = len(emu.servos[1].goals)
        with pytest.raises(LiftFault, match="not homed"):
            lift.rotate(2)
        assert len(emu.servos[1].goals) == moves
        lift.home()
        lift.rotate(2)
        lift.raise_()
        assert lift.status()["height_mm"] == pytest.approx(95.0, abs=0.05)


def test_home_reboots_a_servo_in_hardware_error():
    with rig() as (lift, emu):
        emu.inject("overheating", 2)
        with pytest.raises(LiftFault, match="overheating"):
            lift.rotate(1)
        assert lift.status()["errors"] == {"servo 2": "overheating"}
        lift.home()
        lift.rotate(1)
        assert any(r["event"] == "reboot" and r["id"] == 2 for r in lift.records)


_COMMANDS = st.one_of(
    st.tuples(st.just("move"), st.floats(0.0, 150.0)),
    st.tuples(st.sampled_from(["raise", "lower", "home", "power-cycle"])),
    st.tuples(st.just("rotate"), st.integers(-1, 8)),
)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(start_homed=st.booleans(), commands=st.lists(_COMMANDS, max_size=6))
def test_property_goals_never_leave_the_height_limits(start_homed, commands):
    config = load_config(None, **FAST)
    with rig(config, homed=start_homed) as (lift, emu):
        for command in commands:
            try:
                if command[0] == "power-cycle":
                    emu.inject("power-cycle", config.lift_id)
                elif command[0] == "move":
                    lift.move_to_height(command[1])
                else:
                    getattr(lift, {"raise": "raise_"}.get(command[0], command[0]))(*command[1:])
            except LessError:
                pass
        heights = lift_heights(emu, config)
    slack_mm = 0.05  # one encoder tick is ~0.01 mm here
    assert all(config.min_height_mm - slack_mm <= h <= config.max_height_mm + slack_mm
               for h in heights), heights


@pytest.mark.hardware
@pytest.mark.skipif(not os.environ.get("LESS_LIFT_PORT"), reason="needs a real lift: set LESS_LIFT_PORT")
def test_real_lift_status_and_lower():
    config = load_config(os.environ.get("LESS_LIFT_CONFIG"))
    with DynamixelBus(os.environ["LESS_LIFT_PORT"], config.baud) as bus, ScissorLift(bus, config) as lift:
        status = lift.status()
        assert status["errors"] == {}
        if status["homed"]:
            lift.lower()
            assert lift.status()["height_mm"] == pytest.approx(config.lowered_height_mm, abs=0.5)
