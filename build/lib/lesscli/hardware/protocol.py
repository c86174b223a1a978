"""Dynamixel Protocol 2.0 codec: framing, CRC-16, byte stuffing, instructions and the X-series table.

A packet on the wire is ``FF FF FD 00 | ID | LEN_L LEN_H | INST | params | CRC_L CRC_H`` where LEN counts
the instruction, the (stuffed) parameters and the two CRC bytes, and the CRC-16 (polynomial 0x8005,
initial value 0, no reflection) covers every byte before it, stuffing included. Inside the instruction
and parameters any ``FF FF FD`` is followed by an extra ``FD`` (byte stuffing) so that the header never
appears in the body. Status packets use instruction 0x55 and carry the error byte as the first parameter.
"""

from __future__ import annotations

from dataclasses import dataclass

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
CRC_POLY = 0x8005

# Instructions (Protocol 2.0).
PING, READ, WRITE, REG_WRITE, ACTION, FACTORY_RESET, REBOOT = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x08
CLEAR, STATUS, SYNC_READ, SYNC_WRITE, BULK_READ, BULK_WRITE = 0x10, 0x55, 0x82, 0x83, 0x92, 0x93

# Status packet error field: low 7 bits a code, bit 7 the hardware alert.
ERROR_ALERT = 0x80
ERR_RESULT_FAIL, ERR_INSTRUCTION, ERR_CRC, ERR_DATA_RANGE = 1, 2, 3, 4
ERR_DATA_LENGTH, ERR_DATA_LIMIT, ERR_ACCESS = 5, 6, 7
ERROR_NAMES: dict[int, str] = {
    ERR_RESULT_FAIL: "result fail",
    ERR_INSTRUCTION: "instruction error",
    ERR_CRC: "CRC error",
    ERR_DATA_RANGE: "data range error",
    ERR_DATA_LENGTH: "data length error",
    ERR_DATA_LIMIT: "data limit error",
    ERR_ACCESS: "access error",
}

# Hardware_Error_Status bits (X-series).
HW_INPUT_VOLTAGE, HW_OVERHEATING, HW_ENCODER, HW_ELECTRICAL_SHOCK, HW_OVERLOAD = 0x01, 0x04, 0x08, 0x10, 0x20
HARDWARE_ERROR_NAMES: dict[int, str] = {
    HW_INPUT_VOLTAGE: "input voltage",
    HW_OVERHEATING: "overheating",
    HW_ENCODER: "motor encoder",
    HW_ELECTRICAL_SHOCK: "electrical shock",
    HW_OVERLOAD: "overload",
}

TICKS_PER_TURN = 4096
VELOCITY_UNIT_RPM = 0.229  # Profile_Velocity / Goal_Velocity unit
EEPROM_END = 64  # addresses below are EEPROM: writable only while torque is off
TABLE_SIZE = 147  # X-series control table up to Present_Temperature


@dataclass(frozen=True)
class Register:
    """One control-table entry: byte address, size in bytes, signedness and access."""

    name: str
    address: int
    size: int
    signed: bool = False
    writable: bool = True

    @property
    def eeprom(self) -> bool:
        return self.address < EEPROM_END


_TABLE = [
    ("Model_Number", 0, 2, False, False), ("Model_Information", 2, 4, False, False),
    ("Firmware_Version", 6, 1, False, False), ("ID", 7, 1, False, True), ("Baud_Rate", 8, 1, False, True),
    ("Return_Delay_Time", 9, 1, False, True), ("Drive_Mode", 10, 1, False, True),
    ("Operating_Mode", 11, 1, False, True), ("Secondary_ID", 12, 1, False, True),
    ("Protocol_Type", 13, 1, False, True), ("Homing_Offset", 20, 4, True, True),
    ("Moving_Threshold", 24, 4, False, True), ("Temperature_Limit", 31, 1, False, True),
    ("Max_Voltage_Limit", 32, 2, False, True), ("Min_Voltage_Limit", 34, 2, False, True),
    ("PWM_Limit", 36, 2, False, True), ("Current_Limit", 38, 2, False, True),
    ("Velocity_Limit", 44, 4, False, True), ("Max_Position_Limit", 48, 4, False, True),
    ("Min_Position_Limit", 52, 4, False, True), ("Shutdown", 63, 1, False, True),
    ("Torque_Enable", 64, 1, False, True), ("LED", 65, 1, False, True),
    ("Status_Return_Level", 68, 1, False, True), ("Registered_Instruction", 69, 1, False, False),
    ("Hardware_Error_Status", 70, 1, False, False), ("Goal_PWM", 100, 2, True, True),
    ("Goal_Current", 102, 2, True, True), ("Goal_Velocity", 104, 4, True, True),
    ("Profile_Acceleration", 108, 4, False, True), ("Profile_Velocity", 112, 4, False, True),
    ("Goal_Position", 116, 4, True, True), ("Realtime_Tick", 120, 2, False, False),
    ("Moving", 122, 1, False, False), ("Moving_Status", 123, 1, False, False),
    ("Present_PWM", 124, 2, True, False), ("Present_Current", 126, 2, True, False),
    ("Present_Velocity", 128, 4, True, False), ("Present_Position", 132, 4, True, False),
    ("Velocity_Trajectory", 136, 4, True, False), ("Position_Trajectory", 140, 4, True, False),
    ("Present_Input_Voltage", 144, 2, False, False), ("Present_Temperature", 146, 1, False, False),
]
REGISTERS: dict[str, Register] = {row[0]: Register(*row) for row in _TABLE}
REGISTER_AT: dict[int, Register] = {r.address: r for r in REGISTERS.values()}


def register_name(address: int) -> str:
    """The register name at ``address`` (or ``address N`` when it is not a register start)."""
    reg = REGISTER_AT.get(address)
    return reg.name if reg else f"address {address}"


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ CRC_POLY) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """CRC-16 of ``data`` (polynomial 0x8005, MSB first, initial value ``crc``) as used by Protocol 2.0."""
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` in the instruction + parameter bytes."""
    out = bytearray()
    for byte in body:
        out.append(byte)
        if byte == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Remove the stuffing ``FD`` that follows each ``FF FF FD``."""
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if body[i] == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            i += 1  # skip the stuffing byte
        i += 1
    return bytes(out)


def encode_packet(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A complete packet (header, id, length, stuffed instruction + params, CRC)."""
    body = stuff(bytes([instruction]) + bytes(params))
    length = len(body) + 2
    frame = HEADER + bytes([servo_id, length & 0xFF, length >> 8]) + body
    crc = crc16(frame)
    return frame + bytes([crc & 0xFF, crc >> 8])


def encode_status(servo_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet (instruction 0x55) carrying ``error`` then ``params``."""
    return encode_packet(servo_id, STATUS, bytes([error]) + bytes(params))


@dataclass(frozen=True)
class Packet:
    """A decoded packet: ``params`` are unstuffed; for a status packet ``params[0]`` is the error."""

    servo_id: int
    instruction: int
    params: bytes
    crc_ok: bool = True


class PacketReader:
    """Incremental decoder: feed bytes as they arrive, get complete packets back (garbage is skipped)."""

    MAX_LENGTH = 1024

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[Packet]:
        """Append ``data`` and return every packet completed by it, in order."""
        self._buf.extend(data)
        packets = []
        while True:
            packet = self._next()
            if packet is None:
                return packets
            packets.append(packet)

    def _next(self) -> Packet | None:
        buf = self._buf
        start = buf.find(HEADER)
        if start < 0:
            del buf[: max(0, len(buf) - 3)]  # keep a possible partial header
            return None
        del buf[:start]
        if len(buf) < 7:
            return None
        length = buf[5] | (buf[6] << 8)
        if length < 3 or length > self.MAX_LENGTH:
            del buf[:1]
            return self._next()
        total = 7 + length
        if len(buf) < total:
            return None
        frame = bytes(buf[:total])
        del buf[:total]
        crc_ok = crc16(frame[:-2]) == (frame[-2] | (frame[-1] << 8))
        body = unstuff(frame[7:-2])
        return Packet(frame[4], body[0], body[1:], crc_ok)


def to_signed(value: int, size: int) -> int:
    """Interpret an unsigned ``size``-byte integer as two's complement."""
    bits = 8 * size
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


def to_unsigned(value: int, size: int) -> int:
    """Two's complement bit pattern of ``value`` in ``size`` bytes."""
    return value & ((1 << (8 * size)) - 1)


def pack_value(value: int, size: int) -> bytes:
    """Little-endian bytes of ``value`` (negative values as two's complement)."""
    return to_unsigned(value, size).to_bytes(size, "little")


def unpack_value(data: bytes, signed: bool = False) -> int:
    """Integer from little-endian ``data`` (1, 2 or 4 bytes)."""
    value = int.from_bytes(bytes(data), "little")
    return to_signed(value, len(data)) if signed else value


def hardware_error_text(status: int) -> str:
    """Names of the bits set in Hardware_Error_Status, e.g. ``overload, overheating``."""
    names = [name for bit, name in HARDWARE_ERROR_NAMES.items() if status & bit]
    return ", ".join(names) if names else f"unknown (0x{status:02X})"


def error_text(error: int) -> str:
    """Text of a status packet's error byte, e.g. ``access error (7)``."""
    code = error & ~ERROR_ALERT
    parts = [f"{ERROR_NAMES.get(code, 'unknown error')} ({code})"] if code else []
    if error & ERROR_ALERT:
        parts.append("hardware alert")
    return ", ".join(parts) if parts else "no error"


def rpm_to_ticks_per_s(velocity_units: float) -> float:
    """Profile/Goal velocity (units of 0.229 rev/min) -> encoder ticks per second."""
    return velocity_units * VELOCITY_UNIT_RPM / 60.0 * TICKS_PER_TURN
