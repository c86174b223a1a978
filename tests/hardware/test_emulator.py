"""The pty servo emulator driven by the real ``dynamixel_sdk`` (no monkeypatching), directly and via the
bus."""

import time

import pytest

from lesscli.hardware import protocol as p
from lesscli.hardware.bus import DynamixelBus, ServoError
from lesscli.hardware.emulator import PtyEmulator, ServoEmulator, parse_fault
from lesscli.hardware.servo_model import MODEL_XL430_W250, MODEL_XM430_W350, EmulatedServo, Fault

TIME_SCALE = 500.0
# A pty ignores the baud rate, but the SDK sizes its reply timeout from it: the lowest rate gives the
# emulator thread a wider window on a loaded machine; the bus adds LATENCY_MS, RETRIES covers the rest.
BAUD, RETRIES, LATENCY_MS = 9600, 2, 150.0


def _wait(predicate, timeout_s=5.0):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.002)
    return False


def retry(call, *args):
    """A raw SDK call, repeated on a reply timeout (the emulator thread may be slow on a loaded machine)."""
    import dynamixel_sdk

    for _ in range(RETRIES):
        out = call(*args)
        if dynamixel_sdk.COMM_RX_TIMEOUT not in out:
            return out
    return call(*args)


@pytest.fixture
def emu():
    servos = [EmulatedServo(1, MODEL_XM430_W350, mode=4, true_ticks=5000.0),
              EmulatedServo(2, MODEL_XL430_W250, true_ticks=100.0)]
    emulator = ServoEmulator(servos, time_scale=TIME_SCALE)
    with PtyEmulator(emulator) as pty:
        emulator.port = pty.port
        yield emulator


@pytest.fixture
def sdk(emu):
    import dynamixel_sdk

    port = dynamixel_sdk.PortHandler(emu.port)
    assert port.openPort() and port.setBaudRate(BAUD)
    yield port, dynamixel_sdk.PacketHandler(2.0), dynamixel_sdk
    port.closePort()


@pytest.fixture
def bus(emu):
    with DynamixelBus(emu.port, BAUD, RETRIES, LATENCY_MS) as b:
        yield b


def test_sdk_ping_returns_model_numbers(sdk):
    port, ph, dxl = sdk
    assert retry(ph.ping, port, 1) == (MODEL_XM430_W350, dxl.COMM_SUCCESS, 0)
    assert retry(ph.ping, port, 2)[0] == MODEL_XL430_W250


def test_sdk_missing_id_times_out(sdk):
    port, ph, dxl = sdk
    assert ph.ping(port, 9)[1] == dxl.COMM_RX_TIMEOUT


def test_bus_missing_id_error_names_port_id_and_instruction(bus, emu):
    with pytest.raises(ServoError, match=rf"{emu.port}: servo 9: READ Present_Position: no reply") as exc:
        bus.read(9, "Present_Position")
    assert exc.value.kind == "no-reply"


def test_multi_turn_present_position_is_counted_from_power_up(bus):
    # the shaft sits at 5000 ticks: the count restarts within one turn at power-up
    assert bus.read(1, "Present_Position") == 5000 - 4096


@pytest.mark.parametrize("goal", [-20000, -4097, 37123])
def test_goal_and_present_round_trip_negative_multi_turn(bus, goal):
    bus.write(1, "Profile_Velocity", 0)
    bus.write(1, "Torque_Enable", 1)
    bus.write(1, "Goal_Position", goal)
    assert bus.read(1, "Goal_Position") == goal
    assert _wait(lambda: bus.read(1, "Moving") == 0)
    assert bus.read(1, "Present_Position") == goal


def test_sdk_raw_present_position_is_twos_complement(sdk, bus):
    port, ph, dxl = sdk
    bus.write(1, "Torque_Enable", 1)
    bus.write(1, "Goal_Position", -3)
    assert _wait(lambda: bus.read(1, "Moving") == 0)
    raw, result, error = retry(ph.read4ByteTxRx, port, 1, 132)
    assert (raw, result, error) == (0xFFFFFFFD, dxl.COMM_SUCCESS, 0)


def test_eeprom_write_with_torque_on_is_refused_with_access_error(sdk, bus):
    port, ph, dxl = sdk
    assert retry(ph.write1ByteTxRx, port, 1, 64, 1) == (dxl.COMM_SUCCESS, 0)
    assert retry(ph.write1ByteTxRx, port, 1, 11, 3) == (dxl.COMM_SUCCESS, p.ERR_ACCESS)
    assert bus.read(1, "Operating_Mode") == 4
    with pytest.raises(ServoError, match=r"servo 1: WRITE Homing_Offset=5: access error \(7\).*torque is on"):
        bus.write(1, "Homing_Offset", 5)
    bus.write(1, "Torque_Enable", 0)
    bus.write(1, "Homing_Offset", 5)
    assert bus.read(1, "Homing_Offset") == 5


def test_read_only_register_and_limits(bus):
    with pytest.raises(ServoError, match="access error"):
        bus.write(2, "Present_Position", 10)
    bus.write(2, "Torque_Enable", 1)
    with pytest.raises(ServoError, match="data limit error"):
        bus.write(2, "Goal_Position", 5000)  # position mode 3: 0..4095


def test_sync_write_and_sync_read(bus):
    bus.sync_write({1: 1, 2: 1}, "Torque_Enable")
    assert bus.sync_read([1, 2], "Torque_Enable") == {1: 1, 2: 1}
    bus.sync_write({1: -8000, 2: 2048}, "Goal_Position")
    assert bus.sync_read([1, 2], "Goal_Position") == {1: -8000, 2: 2048}
    assert _wait(lambda: bus.sync_read([1, 2], "Moving") == {1: 0, 2: 0})
    assert bus.sync_read([1, 2], "Present_Position") == {1: -8000, 2: 2048}


def test_sync_read_names_the_missing_servo(bus):
    with pytest.raises(ServoError, match=r"servo 7: SYNC_READ Present_Position: no reply"):
        bus.sync_read([1, 7], "Present_Position")


def test_motion_takes_time_from_profile_velocity():
    servo = EmulatedServo(1, mode=4)
    servo.write(64, bytes([1]), 0.0)
    servo.write(112, p.pack_value(100, 4), 0.0)  # 100 * 0.229 rpm = 1563 ticks/s
    servo.write(116, p.pack_value(3126, 4), 0.0)
    _, half = servo.read(132, 4, 1.0)
    _, moving = servo.read(122, 1, 1.0)
    assert abs(p.unpack_value(half, True) - 1563) <= 1 and moving == b"\x01"
    _, done = servo.read(132, 4, 3.0)
    _, moving = servo.read(122, 1, 3.0)
    assert p.unpack_value(done, True) == 3126 and moving == b"\x00"


def test_mechanical_stop_blocks_velocity_mode():
    servo = EmulatedServo(1, mode=4, true_ticks=3000.0, stop_low=0.0)
    servo.write(64, bytes([0]), 0.0)
    servo.write(11, bytes([1]), 0.0)
    servo.write(64, bytes([1]), 0.0)
    servo.write(104, p.pack_value(-50, 4), 0.0)
    servo.read(132, 4, 100.0)
    assert servo.true_ticks == 0.0 and servo.read(122, 1, 101.0)[1] == b"\x00"


def test_power_cycle_loses_multi_turn_count_and_ram(bus, emu):
    bus.write(1, "Torque_Enable", 1)
    bus.write(1, "LED", 1)
    bus.write(1, "Goal_Position", 20000)
    assert _wait(lambda: bus.read(1, "Moving") == 0)
    emu.inject("power-cycle", 1)
    shaft_ticks = 5000 + (20000 - (5000 - 4096))
    assert bus.read(1, "Present_Position") == shaft_ticks % 4096
    assert (bus.read(1, "Torque_Enable"), bus.read(1, "LED")) == (0, 0)
    assert bus.read(1, "Operating_Mode") == 4  # EEPROM survives


@pytest.mark.parametrize("fault, bit", [("overload", p.HW_OVERLOAD), ("overheating", p.HW_OVERHEATING)])
def test_hardware_error_drops_torque_until_reboot(bus, emu, fault, bit):
    bus.write(2, "Torque_Enable", 1)
    emu.inject(fault, 2)
    assert bus.read(2, "Hardware_Error_Status") == bit and 2 in bus.alerts
    assert bus.read(2, "Torque_Enable") == 0
    with pytest.raises(ServoError, match="result fail"):
        bus.write(2, "Torque_Enable", 1)
    bus.reboot(2)
    assert bus.read(2, "Hardware_Error_Status") == 0
    bus.write(2, "Torque_Enable", 1)


def test_no_reply_fault_with_count_recovers(bus, emu):
    emu.inject("no-reply", 1, count=RETRIES + 1)  # every attempt of the next call goes unanswered
    with pytest.raises(ServoError, match="no reply"):
        bus.ping(1)
    assert bus.ping(1) == MODEL_XM430_W350


def test_bad_crc_fault_reports_corruption(bus, emu):
    emu.inject("bad-crc", 1)
    with pytest.raises(ServoError, match=r"servo 1: READ Moving: corrupted status packet \(CRC mismatch\)"):
        bus.read(1, "Moving")
    assert bus.read(2, "Moving") == 0


def test_stall_fault_never_reaches_goal(bus, emu):
    emu.arm(1, Fault("stall", goal=1))
    bus.write(1, "Torque_Enable", 1)
    bus.write(1, "Goal_Position", 6000)
    time.sleep(0.05)
    assert bus.read(1, "Moving") == 1 and bus.read(1, "Present_Position") != 6000


def test_instruction_packet_with_bad_crc_gets_crc_error(emu):
    packet = p.encode_packet(1, p.PING)
    (status,) = p.PacketReader().feed(emu.handle(p.Packet(1, p.PING, b"", crc_ok=False)))
    assert status.params[0] == p.ERR_CRC and packet


def test_busy_port_is_refused(bus, emu):
    with pytest.raises(ServoError, match=rf"{emu.port}: port is busy"):
        DynamixelBus(emu.port)


def test_missing_port_is_one_clear_error(tmp_path):
    with pytest.raises(ServoError, match=r"nope: cannot open serial port: No such file or directory"):
        DynamixelBus(str(tmp_path / "nope"))


def test_parse_fault_spec():
    assert parse_fault("stall:1:2", 5) == (1, Fault("stall", 2, None))
    assert parse_fault("no-reply:2:0:3", 5) == (2, Fault("no-reply", 0, 3))
    assert parse_fault("overload", 5) == (5, Fault("overload", 1, None))
    with pytest.raises(ValueError, match="unknown fault 'melt'"):
        parse_fault("melt", 1)
