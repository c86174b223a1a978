"""Scissor-lift logic: homing, height moves, insert rotation and the re-orientation cycle.

One servo (extended position mode 4) turns the lead screw of the scissor lift; a second one (position
mode 3) turns the insert among 8 orientations, 45 degrees = 512 ticks apart. Heights are checked against
the configured limits in mm before any command reaches a servo. The lift servo must be homed after every
power-up (its multi-turn count is lost): homing drives down in velocity mode until the lower mechanical
stop halts the screw, makes that point tick 0 through Homing_Offset and lights the servo's LED, a RAM
register that a power cycle or reboot clears, so a lost count is always noticed. Moves wait for arrival
with a timeout, detect stalls, verify the final position, and torque is dropped on every exit.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Self

from lesscli.errors import HardwareError, LessError
from lesscli.hardware import protocol as p
from lesscli.hardware.bus import ServoBus, ServoError
from lesscli.hardware.config import ORIENTATIONS, TICKS_PER_ORIENTATION, LiftConfig

LOG = logging.getLogger("less")
MODE_VELOCITY, MODE_POSITION, MODE_EXTENDED = 1, 3, 4
HOMED_MARK = 1  # LED value on the lift servo once homed since power-up
_BLOCK = (64, 72)  # Torque_Enable .. Present_Position, one READ per poll
_STILL_TICKS = 2  # |change| at or below this counts as not moving (stall / end-stop detection)


class LiftFault(HardwareError):
    """The lift stopped because of a fault; ``fault`` names it (overload, stall, power cycle, ...)."""

    def __init__(self, message: str, fault: str) -> None:
        super().__init__(message)
        self.fault = fault


@dataclass(frozen=True)
class Snapshot:
    """Live state of one servo from a single block read."""

    torque: bool
    led: int
    hardware_error: int
    goal: int
    moving: bool
    position: int

    @classmethod
    def parse(cls, block: bytes) -> Snapshot:
        def at(name: str) -> int:
            reg = p.REGISTERS[name]
            start = reg.address - _BLOCK[0]
            return p.unpack_value(block[start: start + reg.size], reg.signed)

        return cls(bool(at("Torque_Enable")), at("LED"), at("Hardware_Error_Status"), at("Goal_Position"),
                   bool(at("Moving")), at("Present_Position"))


class ScissorLift:
    """The lift over any ``ServoBus``. Use as a context manager: torque is dropped on exit, always.

    Args:
        bus: an open servo bus.
        config: validated lift configuration.
        emit: called with one telemetry record (dict) per poll and per event.
        clock, sleep: time source and sleeper (seconds), injectable for tests.
    """

    def __init__(self, bus: ServoBus, config: LiftConfig, emit: Callable[[dict], None] | None = None,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep):
        self.bus, self.config = bus, config
        self.emit = emit or (lambda record: None)
        self.clock, self.sleep = clock, sleep
        self.t0 = clock()
        self.ids = {"lift": config.lift_id, "rotator": config.rotator_id}
        self.models: dict[int, int] = {}

    # -- lifecycle ----------------------------------------------------------------------------------
    def __enter__(self) -> Self:
        try:
            self.connect()
        except BaseException:
            self.release()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def connect(self) -> None:
        """Ping both servos and put the rotator in position mode (torque off while changing it)."""
        for servo_id in self.ids.values():
            self.models[servo_id] = self.bus.ping(servo_id)
        rot = self.config.rotator_id
        if self.bus.read(rot, "Operating_Mode") != MODE_POSITION:
            self.bus.write(rot, "Torque_Enable", 0)
            self.bus.write(rot, "Operating_Mode", MODE_POSITION)

    def release(self) -> list[str]:
        """Drop torque on every servo (best effort; returns the failures, never raises)."""
        failures = []
        try:
            self.bus.recover()
            self.bus.broadcast_write("Torque_Enable", 0)
        except (ServoError, OSError) as exc:
            failures.append(str(exc))
        answered = [i for i in self.ids.values() if i in self.models]  # skip ids that never answered
        for servo_id in answered or self.ids.values():
            try:
                self.bus.write(servo_id, "Torque_Enable", 0)
            except (ServoError, OSError) as exc:
                failures.append(str(exc))
        for failure in failures:
            LOG.warning("torque off: %s", failure)
        return failures

    # -- state --------------------------------------------------------------------------------------
    def snapshot(self, servo_id: int) -> Snapshot:
        return Snapshot.parse(self.bus.read_block(servo_id, *_BLOCK))

    def homed(self, lift: Snapshot | None = None) -> bool:
        """True when the lift servo was homed since its last power-up."""
        lift = lift or self.snapshot(self.config.lift_id)
        return lift.led == HOMED_MARK and self.bus.read(self.config.lift_id,
                                                        "Operating_Mode") == MODE_EXTENDED

    def height_mm(self, ticks: int) -> float:
        return self.config.geometry.height_for_ticks(ticks)

    def orientation(self, ticks: int) -> int | None:
        """Orientation index at rotator ``ticks`` (None between orientations)."""
        offset = ticks - self.config.rotator_zero_ticks
        k = round(offset / TICKS_PER_ORIENTATION)
        near = abs(offset - k * TICKS_PER_ORIENTATION) <= self.config.tolerance_ticks
        return k if near and 0 <= k < ORIENTATIONS else None

    def status(self, event: str = "status") -> dict:
        """One telemetry record: time, height (mm), rotation (deg), orientation, moving, torque, errors."""
        lift, rot = self.snapshot(self.config.lift_id), self.snapshot(self.config.rotator_id)
        return self._record(event, lift, rot, self.homed(lift))

    def _record(self, event: str, lift: Snapshot, rot: Snapshot, homed: bool) -> dict:
        errors = {f"servo {sid}": p.hardware_error_text(s.hardware_error)
                  for sid,
                  s in ((self.config.lift_id, lift), (self.config.rotator_id, rot)) if s.hardware_error}
        return {
            "time_s": round(self.clock() - self.t0, 4), "event": event, "port": self.bus.port, "homed": homed,
            "height_mm": round(self.height_mm(lift.position), 3) if homed else None,
            "lift_ticks": lift.position,
            "rotator_deg": round((rot.position - self.config.rotator_zero_ticks) * 360.0 / p.TICKS_PER_TURN,
                                 3),
            "orientation": self.orientation(rot.position), "moving": lift.moving or rot.moving,
            "torque": [lift.torque, rot.torque], "errors": errors,
        }

    def _where(self, servo_id: int) -> str:
        role = "lift" if servo_id == self.config.lift_id else "rotator"
        return f"{self.bus.port}: servo {servo_id} ({role})"

    def _check(self, servo_id: int, snap: Snapshot, expect_torque: bool = True) -> None:
        """Raise LiftFault for a hardware error or an unexpected torque drop (power cycle)."""
        if snap.hardware_error:
            text = p.hardware_error_text(snap.hardware_error)
            raise LiftFault(f"{self._where(servo_id)}: Hardware_Error_Status=0x{snap.hardware_error:02X}: "
                            f"{text}; torque is off, 'less lift home' reboots and re-homes",
                            text.split(",")[0])
        if expect_torque and not snap.torque:
            lost = servo_id == self.config.lift_id and snap.led != HOMED_MARK
            detail = "homing mark lost, multi-turn count gone" if lost else "no hardware error reported"
            raise LiftFault(f"{self._where(servo_id)}: Torque_Enable dropped mid-move: power cycle "
                            f"({detail}); run 'less lift home'", "power cycle")

    # -- commands -----------------------------------------------------------------------------------
    def require_homed(self) -> Snapshot:
        lift = self.snapshot(self.config.lift_id)
        self._check(self.config.lift_id, lift, expect_torque=False)
        if not self.homed(lift):
            raise LiftFault(f"{self._where(self.config.lift_id)}: not homed since the last power-up (power "
                            "cycle or reboot cleared the homing mark in LED): run 'less lift home' first",
                            "not homed")
        return lift

    def move_to_height(self, height_mm: float) -> None:
        """Drive the platform to ``height_mm`` (checked against the limits before anything moves)."""
        cfg = self.config
        if not (math.isfinite(height_mm) and cfg.min_height_mm <= height_mm <= cfg.max_height_mm):
            raise LessError(f"height {height_mm:g} mm is outside the lift limits "
                            f"[{cfg.min_height_mm:g}, {cfg.max_height_mm:g}] mm")
        self.require_homed()
        if height_mm > cfg.lowered_height_mm + self._tolerance_mm():  # going into the shell
            rot = self.snapshot(cfg.rotator_id)
            self._check(cfg.rotator_id, rot, expect_torque=False)
            if self.orientation(rot.position) is None:
                raise LiftFault(f"{self._where(cfg.rotator_id)}: insert not at one of the 8 orientations "
                                f"(Present_Position={rot.position}): run 'less lift rotate K' while lowered",
                                "misaligned")
        goal = round(cfg.geometry.ticks_for_height(height_mm))
        self._drive(cfg.lift_id, goal, cfg.lift_velocity)

    def raise_(self) -> None:
        self.move_to_height(self.config.raised_height_mm)

    def lower(self) -> None:
        self.move_to_height(self.config.lowered_height_mm)

    def rotate(self, orientation: int) -> None:
        """Turn the insert to ``orientation`` (0..7); the lift must be lowered (out of the shell)."""
        cfg = self.config
        if not 0 <= orientation < ORIENTATIONS:
            raise LessError(f"orientation {orientation} is outside 0..{ORIENTATIONS - 1}")
        lift = self.require_homed()
        height = self.height_mm(lift.position)
        if height > cfg.lowered_height_mm + self._tolerance_mm():
            raise LiftFault(f"{self._where(cfg.lift_id)}: insert is in the shell (height {height:.1f} mm > "
                            f"lowered {cfg.lowered_height_mm:g} mm): run 'less lift lower' before rotating",
                            "not lowered")
        rot = self.snapshot(cfg.rotator_id)
        self._check(cfg.rotator_id, rot, expect_torque=False)
        self._drive(cfg.rotator_id, cfg.rotator_goal(orientation), cfg.rotator_velocity)

    def cycle(self, orientations: Iterable[int], run: Callable[[int], None] | None = None) -> None:
        """For each orientation: lower, rotate, raise, then ``run(k)`` (which may raise to stop)."""
        orientations = list(orientations)
        for k in orientations:
            if not 0 <= k < ORIENTATIONS:
                raise LessError(f"orientation {k} is outside 0..{ORIENTATIONS - 1}")
        for k in orientations:
            self.lower()
            self.rotate(k)
            self.raise_()
            self.emit({**self.status("orientation"), "target": k})
            if run is not None:
                run(k)

    def _tolerance_mm(self) -> float:
        g = self.config.geometry
        ticks = self.config.tolerance_ticks
        return abs(g.height_for_ticks(g.ticks_for_height(self.config.lowered_height_mm) + ticks)
                   - self.config.lowered_height_mm)

    # -- motion ---------------------------------------------------------------------------------------
    def _drive(self, servo_id: int, goal: int, velocity: int) -> None:
        """Torque on, Goal_Position, wait for arrival, verify; raises LiftFault on any fault."""
        self.bus.write(servo_id, "Profile_Velocity", velocity)
        self.bus.write(servo_id, "Torque_Enable", 1)
        start = self.snapshot(servo_id)
        self._check(servo_id, start)
        self.bus.write(servo_id, "Goal_Position", goal)
        travel_s = abs(goal - start.position) / p.rpm_to_ticks_per_s(velocity)
        deadline = self.clock() + travel_s * self.config.timeout_factor + self.config.timeout_margin_s
        self._wait(servo_id, goal, deadline)

    def _poll(self, servo_id: int, phase: str):
        """Poll one servo every ``poll_s``: yields (snapshot, now, seconds its position has not moved by
        more than _STILL_TICKS), after checking its alarms and logging telemetry for ``phase``."""
        last_pos, still_since = None, self.clock()
        while True:
            snap = self.snapshot(servo_id)
            self._check(servo_id, snap)
            self._telemetry(servo_id, snap, phase)
            now = self.clock()
            if last_pos is None or abs(snap.position - last_pos) > _STILL_TICKS:
                last_pos, still_since = snap.position, now
            yield snap, now, now - still_since
            self.sleep(self.config.poll_s)

    def _wait(self, servo_id: int, goal: int, deadline: float) -> Snapshot:
        cfg = self.config
        for snap, now, still_s in self._poll(servo_id, "move"):
            error = snap.position - goal
            if not snap.moving and abs(error) <= cfg.tolerance_ticks:
                return self._verify(servo_id, goal)
            if still_s > cfg.stall_s and not snap.moving:
                raise LiftFault(f"{self._where(servo_id)}: position error: stopped at Present_Position "
                                f"{snap.position}, {error:+d} ticks from Goal_Position {goal}",
                                "position error")
            if still_s > cfg.stall_s:
                raise LiftFault(f"{self._where(servo_id)}: stall: Present_Position stuck at {snap.position} "
                                f"({error:+d} ticks from Goal_Position {goal}) for {cfg.stall_s:g} s",
                                "stall")
            if now > deadline:
                raise LiftFault(f"{self._where(servo_id)}: stall: Goal_Position {goal} not reached in time "
                                f"(Present_Position {snap.position})", "stall")
        raise AssertionError("unreachable: polling never ends")

    def _verify(self, servo_id: int, goal: int) -> Snapshot:
        snap = self.snapshot(servo_id)
        self._check(servo_id, snap)
        if abs(snap.position - goal) > self.config.tolerance_ticks:
            raise LiftFault(f"{self._where(servo_id)}: position error: Present_Position {snap.position} vs "
                            f"Goal_Position {goal} (tolerance {self.config.tolerance_ticks})",
                            "position error")
        self._telemetry(servo_id, snap, "arrived")
        return snap

    def _telemetry(self, servo_id: int, snap: Snapshot, event: str) -> None:
        other_id = self.config.rotator_id if servo_id == self.config.lift_id else self.config.lift_id
        other = self.snapshot(other_id)
        lift, rot = (snap, other) if servo_id == self.config.lift_id else (other, snap)
        self.emit(self._record(event, lift, rot, lift.led == HOMED_MARK))

    # -- homing ---------------------------------------------------------------------------------------
    def home(self) -> None:
        """Clear hardware errors (REBOOT), find the lower stop, zero the count, mark homed, lower."""
        cfg = self.config
        for servo_id in self.ids.values():
            if self.snapshot(servo_id).hardware_error:
                self.bus.reboot(servo_id)
                self.sleep(cfg.poll_s)
                self.emit({"time_s": round(self.clock() - self.t0, 4), "event": "reboot", "id": servo_id})
        self.connect()
        lift = cfg.lift_id
        self.bus.write(lift, "Torque_Enable", 0)
        self.bus.write(lift, "LED", 0)
        self.bus.write(lift, "Operating_Mode", MODE_VELOCITY)
        self.bus.write(lift, "Torque_Enable", 1)
        self.bus.write(lift, "Goal_Velocity", -cfg.geometry.direction * cfg.homing_velocity)
        try:
            self._wait_for_stop(lift)
        except BaseException:
            self.release()  # never raises, so the original error (or Ctrl-C) is what the caller sees
            raise
        self.bus.write(lift, "Goal_Velocity", 0)
        self.bus.write(lift, "Torque_Enable", 0)
        self.bus.write(lift, "Operating_Mode", MODE_EXTENDED)  # also restarts the turn count
        offset = self.bus.read(lift, "Homing_Offset") - self.bus.read(lift, "Present_Position")
        self.bus.write(lift, "Homing_Offset", offset)
        zero = self.bus.read(lift, "Present_Position")
        if abs(zero) > cfg.tolerance_ticks:
            raise LiftFault(f"{self._where(lift)}: homing: Present_Position {zero} after zeroing", "homing")
        self.bus.write(lift, "LED", HOMED_MARK)
        self.emit(self.status("homed"))
        self.lower()

    def _wait_for_stop(self, servo_id: int) -> None:
        cfg = self.config
        deadline = self.clock() + cfg.homing_timeout_s
        for _snap, now, still_s in self._poll(servo_id, "homing"):
            if still_s > cfg.stall_s:
                return
            if now > deadline:
                raise LiftFault(f"{self._where(servo_id)}: homing: lower stop not found within "
                                f"{cfg.homing_timeout_s:g} s", "homing timeout")
