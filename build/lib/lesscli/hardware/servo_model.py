"""One emulated X-series servo: control table, access rules, time-based motion and injected faults.

The shaft has a physical position ``true_ticks`` (float, encoder ticks) that survives power cycles; the
reported Present_Position is ``round(true_ticks) - origin + Homing_Offset`` where ``origin`` is chosen at
power-up so that the raw count starts within one turn (the multi-turn counter is lost, as on the real
servo). Optional mechanical stops block the shaft. Time is simulated seconds passed in by the caller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from lesscli.hardware import protocol as p

MODEL_XM430_W350 = 1020
MODEL_XL430_W250 = 1060
MODES = {0, 1, 3, 4, 5, 16}  # current, velocity, position, extended position, current-based, PWM
POSITION_MODES = {3, 4, 5}
EXTENDED_LIMIT_TICKS = 1_048_575
MAX_SPEED_UNITS = 200  # speed used when Profile_Velocity is 0
MOTION_FAULTS = {"overload": p.HW_OVERLOAD, "overheating": p.HW_OVERHEATING}
FAULTS = ("no-reply", "bad-crc", "overload", "overheating", "stall", "power-cycle")
_EPS_TICKS = 1e-6

_EEPROM_DEFAULTS = {"Firmware_Version": 48, "Baud_Rate": 1, "Return_Delay_Time": 0,
                    "Operating_Mode": 3, "Protocol_Type": 2, "Moving_Threshold": 10,
                    "Temperature_Limit": 80, "Max_Voltage_Limit": 160, "Min_Voltage_Limit": 95,
                    "PWM_Limit": 885, "Current_Limit": 1193, "Velocity_Limit": 200,
                    "Max_Position_Limit": 4095, "Min_Position_Limit": 0, "Shutdown": 52}
_RAM_DEFAULTS = {"Status_Return_Level": 2, "Present_Input_Voltage": 120, "Present_Temperature": 30}


@dataclass
class Fault:
    """A fault armed on a servo: fires at its ``goal``-th Goal_Position write (0 = at once).

    ``count`` limits how many replies ``no-reply``/``bad-crc`` spoil (None = all from then on).
    """

    name: str
    goal: int = 0
    count: int | None = None


@dataclass
class EmulatedServo:
    """State of one servo. All methods take ``now`` in simulated seconds."""

    servo_id: int
    model_number: int = MODEL_XM430_W350
    true_ticks: float = 0.0
    stop_low: float | None = None
    stop_high: float | None = None
    mode: int = 3
    table: bytearray = field(default_factory=lambda: bytearray(p.TABLE_SIZE))
    faults: list[Fault] = field(default_factory=list)
    goals: list[tuple[float, int, int, float]] = field(default_factory=list)  # (time_s, mode, goal, true)
    spoil: dict[str, int | None] = field(default_factory=dict)  # active reply faults -> remaining count
    stalled: bool = False
    pending: tuple[float, str] | None = None  # (time_s, fault) of a motion fault due mid-move
    origin: int = 0
    last_s: float = 0.0
    speed_ticks_s: float = 0.0
    goal_writes: int = 0

    def __post_init__(self) -> None:
        self.set("Model_Number", self.model_number)
        self.set("ID", self.servo_id)
        for name, value in _EEPROM_DEFAULTS.items():
            self.set(name, value)
        self.set("Operating_Mode", self.mode)
        self.power_cycle(0.0)
        for fault in [f for f in self.faults if f.goal == 0]:
            self.trigger(fault.name, 0.0, fault.count)

    # -- table access -------------------------------------------------------------------------
    def get(self, name: str) -> int:
        reg = p.REGISTERS[name]
        return p.unpack_value(self.table[reg.address: reg.address + reg.size], reg.signed)

    def set(self, name: str, value: int) -> None:
        reg = p.REGISTERS[name]
        self.table[reg.address: reg.address + reg.size] = p.pack_value(int(value), reg.size)

    def power_cycle(self, now: float) -> None:
        """Power loss and restart (also REBOOT): RAM back to defaults, multi-turn counter lost."""
        self.advance(now)
        self.table[p.EEPROM_END:] = bytes(p.TABLE_SIZE - p.EEPROM_END)
        for name, value in _RAM_DEFAULTS.items():
            self.set(name, value)
        self.origin = math.floor(round(self.true_ticks) / p.TICKS_PER_TURN) * p.TICKS_PER_TURN
        self.stalled, self.pending, self.speed_ticks_s = False, None, 0.0
        self.set("Goal_Position", self.present())

    def present(self) -> int:
        return round(self.true_ticks) - self.origin + self.get("Homing_Offset")

    def _true_of(self, position: int) -> float:
        return float(position - self.get("Homing_Offset") + self.origin)

    # -- protocol operations --------------------------------------------------------------------
    def read(self, address: int, length: int, now: float) -> tuple[int, bytes]:
        """READ: (error byte, data)."""
        if address < 0 or length < 1 or address + length > p.TABLE_SIZE:
            return self.error_byte(p.ERR_ACCESS), b""
        self.advance(now)
        self._refresh(now)
        return self.error_byte(0), bytes(self.table[address: address + length])

    def write(self, address: int, data: bytes, now: float) -> int:
        """WRITE: the error byte; nothing is written when it is non-zero (besides the alert bit)."""
        end = address + len(data)
        if address < 0 or not data or end > p.TABLE_SIZE:
            return self.error_byte(p.ERR_ACCESS)
        torque_on = self.get("Torque_Enable") == 1
        for reg in p.REGISTERS.values():
            overlaps = reg.address < end and address < reg.address + reg.size
            if overlaps and (not reg.writable or (reg.eeprom and torque_on)):
                return self.error_byte(p.ERR_ACCESS)
        self.advance(now)
        staged = bytearray(self.table)
        staged[address:end] = data
        code = self._check(staged, address, end)
        if code:
            return self.error_byte(code)
        return self._apply(staged, address, end, now)

    def _check(self, staged: bytearray, address: int, end: int) -> int:
        def value(name: str) -> int:
            reg = p.REGISTERS[name]
            return p.unpack_value(staged[reg.address: reg.address + reg.size], reg.signed)

        touches = lambda name: address <= p.REGISTERS[name].address < end
        if touches("Operating_Mode") and value("Operating_Mode") not in MODES:
            return p.ERR_DATA_RANGE
        if touches("Torque_Enable") and value("Torque_Enable") not in (0, 1):
            return p.ERR_DATA_RANGE
        if touches("Goal_Position"):
            goal, mode = value("Goal_Position"), value("Operating_Mode")
            low, high = (value("Min_Position_Limit"), value("Max_Position_Limit")) if mode == 3 else (
                -EXTENDED_LIMIT_TICKS, EXTENDED_LIMIT_TICKS)
            if not low <= goal <= high:
                return p.ERR_DATA_LIMIT
        if touches("Goal_Velocity") and abs(value("Goal_Velocity")) > value("Velocity_Limit"):
            return p.ERR_DATA_LIMIT
        return 0

    def _apply(self, staged: bytearray, address: int, end: int, now: float) -> int:
        was_on = self.get("Torque_Enable") == 1
        if self.get("Hardware_Error_Status") and staged[64] == 1 and not was_on:
            return self.error_byte(p.ERR_RESULT_FAIL)  # shut down: torque stays off until reboot
        self.table[:] = staged
        if address <= 11 < end:
            self.mode = self.get("Operating_Mode")
            self.origin = math.floor(round(self.true_ticks) / p.TICKS_PER_TURN) * p.TICKS_PER_TURN
        if address <= 64 < end and self.get("Torque_Enable") == 1 and not was_on:
            self.set("Goal_Position", self.present())  # hold where it is
        elif address <= 116 < end:
            self._goal_written(now)
        return self.error_byte(0)

    def _goal_written(self, now: float) -> None:
        goal = self.get("Goal_Position")
        self.goals.append((now, self.mode, goal, self._true_of(goal)))
        self.goal_writes += 1
        for fault in [f for f in self.faults if f.goal == self.goal_writes]:
            self.faults.remove(fault)
            if fault.name in ("no-reply", "bad-crc", "stall"):
                self.trigger(fault.name, now, fault.count)
            else:
                speed = self._speed()
                travel_s = abs(self._true_of(goal) - self.true_ticks) / speed if speed > 0 else 0.0
                self.pending = (now + 0.5 * travel_s, fault.name)

    def trigger(self, name: str, now: float, count: int | None = None) -> None:
        """Make fault ``name`` happen now (see ``FAULTS``)."""
        self.advance(now)
        if name in ("no-reply", "bad-crc"):
            self.spoil[name] = count
        elif name == "stall":
            self.stalled = True
        elif name == "power-cycle":
            self.power_cycle(now)
        elif name in MOTION_FAULTS:
            self.set("Hardware_Error_Status", self.get("Hardware_Error_Status") | MOTION_FAULTS[name])
            self.set("Torque_Enable", 0)
            if name == "overheating":
                self.set("Present_Temperature", self.get("Temperature_Limit") + 1)
        else:
            raise ValueError(f"unknown fault '{name}' (known: {', '.join(FAULTS)})")

    def take_reply_fault(self) -> str | None:
        """The reply fault spoiling the next status packet, if any (counts it down)."""
        for name in ("no-reply", "bad-crc"):
            if name in self.spoil:
                left = self.spoil[name]
                if left is not None:
                    if left <= 1:
                        del self.spoil[name]
                    else:
                        self.spoil[name] = left - 1
                return name
        return None

    def error_byte(self, code: int) -> int:
        return code | (p.ERROR_ALERT if self.get("Hardware_Error_Status") else 0)

    # -- motion ---------------------------------------------------------------------------------
    def _speed(self) -> float:
        units = self.get("Profile_Velocity") or MAX_SPEED_UNITS
        return p.rpm_to_ticks_per_s(min(units, self.get("Velocity_Limit") or MAX_SPEED_UNITS))

    def _target(self, even_stalled: bool = False) -> tuple[float, float] | None:
        """(target true ticks, speed ticks/s) of the current command, None when not driving."""
        if self.get("Torque_Enable") != 1 or (self.stalled and not even_stalled):
            return None
        if self.mode in POSITION_MODES:
            return self._true_of(self.get("Goal_Position")), self._speed()
        if self.mode == 1:
            velocity = p.rpm_to_ticks_per_s(self.get("Goal_Velocity"))
            return (math.inf if velocity > 0 else -math.inf), abs(velocity)
        return None

    def advance(self, now: float) -> None:
        """Move the shaft up to ``now``, firing a pending mid-move fault on the way."""
        if self.pending is not None and self.pending[0] <= now:
            due, name = self.pending
            self.pending = None
            self._move(due)
            self.trigger(name, due)
        self._move(now)

    def _move(self, now: float) -> None:
        dt = now - self.last_s
        if dt <= 0:
            return
        self.last_s = now
        target = self._target()
        before = self.true_ticks
        if target is not None:
            goal, speed = target
            step = min(abs(goal - before), speed * dt)
            moved = before + math.copysign(step, goal - before)
            low = -math.inf if self.stop_low is None else self.stop_low
            high = math.inf if self.stop_high is None else self.stop_high
            self.true_ticks = min(max(moved, min(low, before)), max(high, before))
        self.speed_ticks_s = (self.true_ticks - before) / dt

    def _refresh(self, now: float) -> None:
        """Write the live (read-only) registers from the state."""
        target = self._target(even_stalled=True)
        rolling = abs(self.speed_ticks_s) > _EPS_TICKS
        if target is None:
            moving = False
        elif self.mode in POSITION_MODES:
            moving = abs(target[0] - self.true_ticks) > self.get("Moving_Threshold")
        else:
            moving = rolling or self.stalled
        self.set("Moving", int(moving))
        self.set("Present_Position", self.present())
        self.set("Present_Velocity", round(self.speed_ticks_s / p.rpm_to_ticks_per_s(1.0)))
        self.set("Realtime_Tick", int(now * 1000) % 32768)
