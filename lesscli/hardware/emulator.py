"""A stateful Protocol 2.0 multi-servo emulator on a pseudo-terminal.

``ServoEmulator`` answers PING, READ, WRITE, SYNC_READ, SYNC_WRITE and REBOOT packets for a set of
``EmulatedServo`` objects; ``PtyEmulator`` serves it on a pty from a background thread, so any serial
client (the real ``dynamixel_sdk`` included) can open the slave path. Time runs ``time_scale`` times
faster than the wall clock, so motions that take seconds on the lift take milliseconds in tests.

Faults (``FAULTS``): ``no-reply`` and ``bad-crc`` spoil status packets, ``overload`` and ``overheating``
set Hardware_Error_Status and drop torque half way through a move, ``stall`` freezes the shaft so the
goal is never reached, ``power-cycle`` resets RAM and loses the multi-turn counter half way through a move.
"""

from __future__ import annotations

import json
import os
import select
import threading
import time
import tty
from collections.abc import Iterable
from typing import IO, Self

from lesscli.hardware import protocol as p
from lesscli.hardware.config import LiftConfig
from lesscli.hardware.servo_model import FAULTS, MODEL_XL430_W250, MODEL_XM430_W350, EmulatedServo, Fault

_POLL_S = 0.05


def parse_fault(spec: str, default_id: int) -> tuple[int, Fault]:
    """``NAME[:ID[:N[:COUNT]]]`` -> (servo id, Fault). N: fire at the N-th Goal_Position write (0 = now).

    Raises:
        ValueError: unknown fault name or non-integer fields.
    """
    parts = spec.split(":")
    name = parts[0]
    if name not in FAULTS:
        raise ValueError(f"unknown fault '{name}' (known: {', '.join(FAULTS)})")
    try:
        numbers = [int(x) for x in parts[1:]]
    except ValueError:
        raise ValueError(f"fault '{spec}': expected NAME[:ID[:N[:COUNT]]] with integers") from None
    servo_id = numbers[0] if numbers else default_id
    goal = numbers[1] if len(numbers) > 1 else 1
    count = numbers[2] if len(numbers) > 2 else None
    return servo_id, Fault(name, goal, count)


def lift_servos(config: LiftConfig, start_height_mm: float | None = None) -> list[EmulatedServo]:
    """The two servos of an emulated lift: a screw servo with its lower mechanical stop at true tick 0
    (a stop above 0 when ``direction`` is -1) and the platform at ``start_height_mm`` (default: mid-range),
    and a rotator somewhere between orientations, as after an unknown previous run.
    """
    g = config.geometry
    height = start_height_mm if start_height_mm is not None else 0.5 * (config.min_height_mm
                                                                        + config.max_height_mm)
    stop = {"stop_low": 0.0} if g.direction > 0 else {"stop_high": 0.0}
    lift = EmulatedServo(config.lift_id, MODEL_XM430_W350, true_ticks=g.ticks_for_height(height), mode=4,
                         **stop)
    rotator = EmulatedServo(config.rotator_id, MODEL_XL430_W250, true_ticks=config.rotator_zero_ticks + 300.0)
    return [lift, rotator]


class ServoEmulator:
    """Packet-level behaviour of several servos sharing one bus (thread-safe)."""

    def __init__(self, servos: Iterable[EmulatedServo], time_scale: float = 1.0,
                 log: IO[str] | None = None) -> None:
        self.servos = {s.servo_id: s for s in servos}
        self.time_scale = float(time_scale)
        self.lock = threading.RLock()
        self.log = log
        self._t0 = time.monotonic()
        self._last_goals = {sid: 0 for sid in self.servos}

    def now(self) -> float:
        """Simulated seconds since start."""
        return (time.monotonic() - self._t0) * self.time_scale

    def inject(self, name: str, servo_id: int, count: int | None = None) -> None:
        """Make fault ``name`` happen now on ``servo_id``."""
        with self.lock:
            self.servos[servo_id].trigger(name, self.now(), count)
            self._event({"event": "fault", "fault": name, "id": servo_id})

    def arm(self, servo_id: int, fault: Fault) -> None:
        """Arm ``fault`` on ``servo_id`` (fires at its N-th Goal_Position write from now on)."""
        with self.lock:
            servo = self.servos[servo_id]
            if fault.goal == 0:
                self.inject(fault.name, servo_id, fault.count)
            else:
                servo.faults.append(Fault(fault.name, servo.goal_writes + fault.goal, fault.count))

    def handle(self, packet: p.Packet) -> bytes:
        """Reply bytes (possibly empty) for one instruction packet."""
        with self.lock:
            now = self.now()
            targets = sorted(self.servos) if packet.servo_id == p.BROADCAST_ID else [packet.servo_id]
            if not packet.crc_ok:
                return b"".join(self._status(sid, p.ERR_CRC) for sid in targets if sid in self.servos)
            handler = _HANDLERS.get(packet.instruction)
            if handler is None:
                return b"".join(self._status(sid, p.ERR_INSTRUCTION) for sid in targets if sid in self.servos)
            reply = handler(self, packet, now)
            self._log_goals()
            return reply

    def _status(self, servo_id: int, error: int, params: bytes = b"") -> bytes:
        """A status packet from ``servo_id``, unless a reply fault eats or corrupts it."""
        servo = self.servos[servo_id]
        fault = servo.take_reply_fault()
        if fault == "no-reply":
            return b""
        packet = p.encode_status(servo_id, servo.error_byte(error), params)
        if fault == "bad-crc":
            packet = packet[:-1] + bytes([packet[-1] ^ 0xFF])
        return packet

    def _ping(self, packet: p.Packet, now: float) -> bytes:
        ids = sorted(self.servos) if packet.servo_id == p.BROADCAST_ID else [packet.servo_id]
        out = b""
        for sid in ids:
            if sid in self.servos:
                servo = self.servos[sid]
                info = p.pack_value(servo.get("Model_Number"), 2) + bytes([servo.get("Firmware_Version")])
                out += self._status(sid, 0, info)
        return out

    def _read(self, packet: p.Packet, now: float) -> bytes:
        servo = self.servos.get(packet.servo_id)
        if servo is None or len(packet.params) != 4:
            return b"" if servo is None else self._status(packet.servo_id, p.ERR_DATA_LENGTH)
        address, length = p.unpack_value(packet.params[:2]), p.unpack_value(packet.params[2:])
        error, data = servo.read(address, length, now)
        return self._status(packet.servo_id, error, data)

    def _write(self, packet: p.Packet, now: float) -> bytes:
        if len(packet.params) < 3:
            return b""
        address, data = p.unpack_value(packet.params[:2]), packet.params[2:]
        if packet.servo_id == p.BROADCAST_ID:
            for servo in self.servos.values():
                servo.write(address, data, now)
            return b""
        servo = self.servos.get(packet.servo_id)
        if servo is None:
            return b""
        return self._status(packet.servo_id, servo.write(address, data, now))

    def _sync_read(self, packet: p.Packet, now: float) -> bytes:
        address, length = p.unpack_value(packet.params[:2]), p.unpack_value(packet.params[2:4])
        out = b""
        for sid in packet.params[4:]:
            if sid in self.servos:
                error, data = self.servos[sid].read(address, length, now)
                out += self._status(sid, error, data)
        return out

    def _sync_write(self, packet: p.Packet, now: float) -> bytes:
        address, length = p.unpack_value(packet.params[:2]), p.unpack_value(packet.params[2:4])
        body = packet.params[4:]
        for i in range(0, len(body) - length, length + 1):
            sid = body[i]
            if sid in self.servos:
                self.servos[sid].write(address, body[i + 1: i + 1 + length], now)
        return b""

    def _reboot(self, packet: p.Packet, now: float) -> bytes:
        servo = self.servos.get(packet.servo_id)
        if servo is None:
            return b""
        reply = self._status(packet.servo_id, 0)
        servo.set("Hardware_Error_Status", 0)
        servo.power_cycle(now)
        self._event({"event": "reboot", "id": packet.servo_id})
        return reply

    def _log_goals(self) -> None:
        for sid, servo in self.servos.items():
            for time_s, mode, goal, true in servo.goals[self._last_goals[sid]:]:
                self._event({"event": "goal", "id": sid, "time_s": round(time_s, 6), "mode": mode,
                             "goal": goal, "true_ticks": true})
            self._last_goals[sid] = len(servo.goals)

    def _event(self, record: dict) -> None:
        if self.log is not None:
            self.log.write(json.dumps(record) + "\n")
            self.log.flush()


_HANDLERS = {p.PING: ServoEmulator._ping, p.READ: ServoEmulator._read, p.WRITE: ServoEmulator._write,
             p.SYNC_READ: ServoEmulator._sync_read, p.SYNC_WRITE: ServoEmulator._sync_write,
             p.REBOOT: ServoEmulator._reboot}


class PtyEmulator:
    """Serve a ``ServoEmulator`` on a pseudo-terminal from a daemon thread.

    Use as a context manager; ``port`` is the slave path (or ``link``, a symlink to it, when given).
    """

    def __init__(self, emulator: ServoEmulator, link: str | None = None) -> None:
        self.emulator = emulator
        self.link = link
        self.port = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._fds: tuple[int, int] | None = None

    def start(self) -> str:
        """Open the pty, start serving, return the port path."""
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing, 8-bit clean
        self._fds = (master, slave)  # keep the slave open so the master never sees a hang-up
        self.port = os.ttyname(slave)
        if self.link:
            if os.path.islink(self.link):
                os.unlink(self.link)
            os.symlink(self.port, self.link)
            self.port = self.link
        self._thread = threading.Thread(target=self._serve, name="servo-emulator", daemon=True)
        self._thread.start()
        return self.port

    def stop(self) -> None:
        """Stop serving, close the pty and remove the link."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._fds is not None:
            for fd in self._fds:
                os.close(fd)
            self._fds = None
        if self.link and os.path.islink(self.link):
            os.unlink(self.link)

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _serve(self) -> None:
        master = self._fds[0]
        reader = p.PacketReader()
        while not self._stop.is_set():
            ready, _, _ = select.select([master], [], [], _POLL_S)
            if not ready:
                continue
            try:
                data = os.read(master, 4096)
            except OSError:
                continue
            for packet in reader.feed(data):
                reply = self.emulator.handle(packet)
                if reply:
                    os.write(master, reply)
