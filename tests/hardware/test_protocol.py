"""Protocol 2.0 codec: CRC, stuffing and framing against hand-checked packets and the SDK's own codec."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lesscli.hardware import protocol as p

# Example packets from the Protocol 2.0 documentation (instruction and status examples).
PING_ID1 = bytes.fromhex("FFFFFD0001030001194E")
READ_PRESENT_POSITION_ID1 = bytes.fromhex("FFFFFD0001070002840004001D15")
WRITE_GOAL_512_ID1 = bytes.fromhex("FFFFFD00010900037400000200 00CA89".replace(" ", ""))


@pytest.mark.parametrize("packet, servo_id, instruction, params", [
    (PING_ID1, 1, p.PING, b""),
    (READ_PRESENT_POSITION_ID1, 1, p.READ, bytes([0x84, 0x00, 0x04, 0x00])),
    (WRITE_GOAL_512_ID1, 1, p.WRITE, bytes([0x74, 0x00, 0x00, 0x02, 0x00, 0x00])),
])
def test_known_packets_encode_and_decode(packet, servo_id, instruction, params):
    assert p.encode_packet(servo_id, instruction, params) == packet
    (decoded,) = p.PacketReader().feed(packet)
    assert decoded == p.Packet(servo_id, instruction, params, True)


def test_crc_matches_the_sdk_table_for_random_bytes():
    import numpy as np
    from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

    sdk = Protocol2PacketHandler()
    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 31, 200):
        data = bytes(rng.integers(0, 256, n, dtype=np.uint8))
        assert p.crc16(data) == sdk.updateCRC(0, list(data), n)


def test_stuffing_inserts_fd_after_header_pattern_and_round_trips():
    body = bytes([0x03, 0xFF, 0xFF, 0xFD, 0x10, 0xFF, 0xFF, 0xFD])
    assert p.stuff(body) == bytes([0x03, 0xFF, 0xFF, 0xFD, 0xFD, 0x10, 0xFF, 0xFF, 0xFD, 0xFD])
    assert p.unstuff(p.stuff(body)) == body


def test_stuffed_packet_matches_the_sdk():
    from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

    params = bytes([0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00])
    ours = p.encode_packet(7, p.WRITE, params)
    pkt = [0xFF, 0xFF, 0xFD, 0x00, 7, len(params) + 3, 0, p.WRITE, *params, 0, 0]
    stuffed = Protocol2PacketHandler().addStuffing(pkt)
    n = stuffed[5] | stuffed[6] << 8
    crc = p.crc16(bytes(stuffed[: 7 + n - 2]))
    assert ours == bytes(stuffed[: 7 + n - 2]) + bytes([crc & 0xFF, crc >> 8])
    assert ours.count(b"\xff\xff\xfd\xfd") == 1


@settings(max_examples=60, deadline=None)
@given(servo_id=st.integers(0, 253), instruction=st.sampled_from([p.PING, p.READ, p.WRITE, p.SYNC_WRITE]),
       params=st.binary(max_size=40), junk=st.binary(max_size=8), cut=st.integers(0, 60))
def test_reader_round_trips_with_junk_and_split_feeds(servo_id, instruction, params, junk, cut):
    packet = p.encode_packet(servo_id, instruction, params)
    stream = junk.replace(b"\xff\xff\xfd", b"") + packet
    reader = p.PacketReader()
    got = reader.feed(stream[:cut]) + reader.feed(stream[cut:])
    assert got == [p.Packet(servo_id, instruction, params, True)]


def test_reader_flags_a_bad_crc():
    bad = PING_ID1[:-1] + bytes([PING_ID1[-1] ^ 0x01])
    (packet,) = p.PacketReader().feed(bad)
    assert not packet.crc_ok


def test_status_packet_carries_error_first():
    (packet,) = p.PacketReader().feed(p.encode_status(3, p.ERR_ACCESS, b"\x01\x02"))
    assert (packet.instruction, packet.params) == (p.STATUS, bytes([p.ERR_ACCESS, 1, 2]))


@pytest.mark.parametrize("value, size, raw", [
    (-1, 4, 0xFFFFFFFF), (-20000, 4, 0xFFFFB1E0), (2**31 - 1, 4, 0x7FFFFFFF), (-(2**31), 4, 0x80000000),
    (-2, 2, 0xFFFE), (5, 1, 5),
])
def test_signed_conversions(value, size, raw):
    assert p.to_unsigned(value, size) == raw
    assert p.to_signed(raw, size) == value
    assert p.unpack_value(p.pack_value(value, size), signed=True) == value


def test_register_table_addresses_from_the_x_series_manual():
    expected = {"Operating_Mode": 11, "Torque_Enable": 64, "Hardware_Error_Status": 70,
                "Profile_Velocity": 112, "Goal_Position": 116, "Moving": 122, "Present_Position": 132}
    assert {name: p.REGISTERS[name].address for name in expected} == expected
    assert p.REGISTERS["Present_Position"].signed and not p.REGISTERS["Present_Position"].writable
    assert p.REGISTERS["Operating_Mode"].eeprom and not p.REGISTERS["Goal_Position"].eeprom


def test_error_texts_name_the_fault():
    assert p.error_text(p.ERR_ACCESS) == "access error (7)"
    assert p.hardware_error_text(p.HW_OVERLOAD | p.HW_OVERHEATING) == "overheating, overload"
