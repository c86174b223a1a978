"""A small servo-bus interface and its implementation over the real ``dynamixel_sdk`` (Protocol 2.0).

Registers are addressed by name (``protocol.REGISTERS``); signed registers (Present_Position,
Goal_Position, Homing_Offset, ...) come back as signed Python ints. Every failure raises
``ServoError`` (a ``HardwareError``) whose message names the port, the servo id and the register.
A hardware alert (bit 7 of a status packet's error byte) is not an exception here: it is recorded in
``alerts`` and the caller reads Hardware_Error_Status to name the fault.
"""

from __future__ import annotations

import fcntl
import os
from typing import Protocol as Interface
from typing import Self

from lesscli.errors import HardwareError
from lesscli.hardware import protocol as p

DEFAULT_BAUD = 57600


class ServoError(HardwareError):
    """A servo bus failure. ``kind`` is 'no-reply', 'corrupt', 'packet', 'port' or 'busy'."""

    def __init__(self, message: str, kind: str, code: int = 0) -> None:
        super().__init__(message)
        self.kind = kind
        self.code = code


class ServoBus(Interface):
    """What the lift needs from a servo bus."""

    port: str

    def ping(self, servo_id: int) -> int: ...
    def recover(self) -> None: ...
    def read(self, servo_id: int, register: str) -> int: ...
    def read_block(self, servo_id: int, address: int, length: int) -> bytes: ...
    def write(self, servo_id: int, register: str, value: int) -> None: ...
    def broadcast_write(self, register: str, value: int) -> None: ...
    def sync_read(self, ids: list[int], register: str) -> dict[int, int]: ...
    def sync_write(self, values: dict[int, int], register: str) -> None: ...
    def reboot(self, servo_id: int) -> None: ...
    def close(self) -> None: ...


def _port_handler(sdk, port: str, latency_ms: float):
    """The SDK's PortHandler, or a subclass that adds ``latency_ms`` to every reply timeout."""
    if latency_ms <= 0:
        return sdk.PortHandler(port)

    class SlowLinkPortHandler(sdk.PortHandler):
        def setPacketTimeout(self, packet_length):
            super().setPacketTimeout(packet_length)
            self.packet_timeout += latency_ms

        def setPacketTimeoutMillis(self, msec):
            super().setPacketTimeoutMillis(msec + latency_ms)

    return SlowLinkPortHandler(port)


class DynamixelBus:
    """``ServoBus`` over ``dynamixel_sdk``'s PortHandler/PacketHandler on a serial port (or pty).

    Args:
        port: serial device path, e.g. ``/dev/ttyUSB0``.
        baud: baud rate (one the SDK supports).
        retries: extra attempts after a timeout or a corrupted reply (register access is idempotent).
        latency_ms: added to the SDK's reply timeout (it assumes a 16 ms USB latency timer); raise it for
            slow adapters, or for an emulator on a loaded machine. 0 keeps the SDK's timing.

    Raises:
        ServoError: the port is missing, busy, or the baud rate is unsupported.
    """

    def __init__(self, port: str, baud: int = DEFAULT_BAUD, retries: int = 1,
                 latency_ms: float = 0.0) -> None:
        import dynamixel_sdk as sdk
        import serial

        self.port, self.baud, self.retries = port, baud, retries
        self._sdk = sdk
        self.alerts: set[int] = set()
        self._port = _port_handler(sdk, port, latency_ms)
        self._packets = sdk.PacketHandler(2.0)
        try:
            ok = self._port.openPort() and self._port.setBaudRate(baud)
        except (serial.SerialException, OSError) as exc:
            errno = getattr(exc, "errno", None)
            reason = os.strerror(errno) if isinstance(errno, int) else str(exc) or type(exc).__name__
            raise ServoError(f"{port}: cannot open serial port: {reason}", "port") from None
        if not ok:
            self._close_quietly()
            raise ServoError(f"{port}: baud rate {baud} is not supported by the servo bus", "port")
        try:  # one process per bus: a second one would garble the traffic
            fcntl.flock(self._port.ser.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._close_quietly()
            raise ServoError(f"{port}: port is busy (another program has it open)", "busy") from None

    # -- helpers ---------------------------------------------------------------------------------
    def _fail(self, servo_id: int | str, what: str, result: int, error: int) -> None:
        sdk = self._sdk
        where = f"{self.port}: servo {servo_id}: {what}"
        if result == sdk.COMM_RX_TIMEOUT:
            raise ServoError(f"{where}: no reply (timeout; check id, wiring, power and baud rate)",
                             "no-reply")
        if result == sdk.COMM_RX_CORRUPT:
            raise ServoError(f"{where}: corrupted status packet (CRC mismatch)", "corrupt")
        if result != sdk.COMM_SUCCESS:
            raise ServoError(f"{where}: {self._packets.getTxRxResult(result)}", "port", result)
        code = error & ~p.ERROR_ALERT
        if code:
            hint = " (EEPROM is locked while torque is on)" if code == p.ERR_ACCESS else ""
            raise ServoError(f"{where}: {p.error_text(code)}{hint}", "packet", code)

    def _call(self, servo_id: int | str, what: str, fn, *args):
        """Run an SDK call returning (..., result, error) with retries on timeouts and bad CRC."""
        for attempt in range(self.retries + 1):
            out = fn(self._port, *args)
            result, error = out[-2], out[-1]
            if result in (self._sdk.COMM_RX_TIMEOUT, self._sdk.COMM_RX_CORRUPT) and attempt < self.retries:
                continue
            if isinstance(servo_id, int) and error & p.ERROR_ALERT:
                self.alerts.add(servo_id)
            self._fail(servo_id, what, result, error)
            return out[0] if len(out) == 3 else None
        return None

    # -- ServoBus ------------------------------------------------------------------------------------
    def ping(self, servo_id: int) -> int:
        """Model number of ``servo_id``."""
        return self._call(servo_id, "PING", self._packets.ping, servo_id)

    def read_block(self, servo_id: int, address: int, length: int) -> bytes:
        """``length`` raw bytes of the control table from ``address``."""
        what = f"READ {p.register_name(address)} (+{length} bytes)"
        data = self._call(servo_id, what, self._packets.readTxRx, servo_id, address, length)
        if len(data) != length:
            raise ServoError(f"{self.port}: servo {servo_id}: {what}: short reply", "corrupt")
        return bytes(data)

    def read(self, servo_id: int, register: str) -> int:
        """Value of ``register`` (signed registers decoded as two's complement)."""
        reg = p.REGISTERS[register]
        data = self._call(servo_id, f"READ {register}", self._packets.readTxRx, servo_id, reg.address,
                          reg.size)
        return p.unpack_value(bytes(data), reg.signed)

    def write(self, servo_id: int, register: str, value: int) -> None:
        """Write ``value`` to ``register`` and check the status packet."""
        reg = p.REGISTERS[register]
        data = list(p.pack_value(value, reg.size))
        self._call(servo_id, f"WRITE {register}={value}", self._write_rx, servo_id, reg.address, reg.size,
                   data)

    def _write_rx(self, port, servo_id, address, size, data):
        result, error = self._packets.writeTxRx(port, servo_id, address, size, data)
        return result, error

    def broadcast_write(self, register: str, value: int) -> None:
        """Write ``register`` on every servo at once (no status packets come back)."""
        reg = p.REGISTERS[register]
        data = list(p.pack_value(value, reg.size))
        result = self._packets.writeTxOnly(self._port, p.BROADCAST_ID, reg.address, reg.size, data)
        self._fail("broadcast", f"WRITE {register}={value}", result, 0)

    def sync_read(self, ids: list[int], register: str) -> dict[int, int]:
        """``register`` of several servos in one SYNC_READ."""
        reg = p.REGISTERS[register]
        group = self._sdk.GroupSyncRead(self._port, self._packets, reg.address, reg.size)
        for servo_id in ids:
            group.addParam(servo_id)
        for attempt in range(self.retries + 1):
            result = group.txRxPacket()
            if result == self._sdk.COMM_SUCCESS or attempt == self.retries:
                break
        if result != self._sdk.COMM_SUCCESS:  # the SDK stops at the first servo that failed
            failed = next((i for i in ids if not group.data_dict.get(i)), ids[0])
            self._fail(failed, f"SYNC_READ {register}", result, 0)
        return {i: p.to_signed(group.getData(i, reg.address, reg.size), reg.size) if reg.signed
                else group.getData(i, reg.address, reg.size) for i in ids}

    def sync_write(self, values: dict[int, int], register: str) -> None:
        """Write ``register`` on several servos in one SYNC_WRITE (no status packets)."""
        reg = p.REGISTERS[register]
        group = self._sdk.GroupSyncWrite(self._port, self._packets, reg.address, reg.size)
        for servo_id, value in values.items():
            group.addParam(servo_id, list(p.pack_value(value, reg.size)))
        self._fail(",".join(map(str, values)), f"SYNC_WRITE {register}", group.txPacket(), 0)

    def reboot(self, servo_id: int) -> None:
        """REBOOT (clears a hardware error; the multi-turn count is lost)."""
        self._call(servo_id, "REBOOT", self._packets.reboot, servo_id)
        self.alerts.discard(servo_id)

    def recover(self) -> None:
        """Make the port usable after a transaction was cut short (e.g. by Ctrl-C in the middle of it)."""
        self._port.is_using = False
        try:
            self._port.clearPort()
        except OSError:
            pass

    def close(self) -> None:
        """Release the port."""
        self._close_quietly()

    def _close_quietly(self) -> None:
        try:
            if self._port.ser is not None:
                self._port.closePort()
        except OSError:
            pass

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
