"""LX-15D packets: known byte vectors, round trips (hypothesis), resynchronisation in a noisy stream."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware import constants as C
from hardware.errors import ChecksumError, ProtocolError
from hardware.protocol import Packet, StreamDecoder, checksum, decode, encode, encode_reply, encode_request


@pytest.mark.parametrize(
    "packet, expected",
    [
        (encode_request(1, C.MOVE_TIME_WRITE, 500, 1000), "55 55 01 07 01 f4 01 e8 03 16"),
        (encode_request(1, C.POS_READ), "55 55 01 03 1c df"),
        (encode_request(254, C.LOAD_OR_UNLOAD_WRITE, 0), "55 55 fe 04 1f 00 de"),
        (encode_request(254, C.MOVE_START), "55 55 fe 03 0b f3"),
        (encode_request(3, C.ANGLE_OFFSET_ADJUST, -10), "55 55 03 04 11 f6 f1"),
        (encode_request(254, C.ID_WRITE, 7), "55 55 fe 04 0d 07 e9"),
        (encode_reply(1, C.POS_READ, -5), "55 55 01 05 1c fb ff e3"),
        (encode_reply(2, C.VIN_READ, 7400), "55 55 02 05 1b e8 1c d9"),
    ],
)
def test_known_vectors(packet, expected):
    assert packet.hex(" ") == expected
    raw = bytes.fromhex(expected)
    assert decode(raw).to_bytes() == raw


def test_command_table_matches_protocol():
    codes = {c.name: c.code for c in C.COMMANDS.values()}
    assert codes["MOVE_TIME_WRITE"] == 1 and codes["POS_READ"] == 28 and codes["LED_ERROR_READ"] == 36
    assert len(C.COMMANDS) == 28
    assert C.MOVE_TIME_WRITE.request_len == 7 and C.POS_READ.reply_len == 5 and C.MOVE_STOP.request_len == 3
    for c in C.COMMANDS.values():  # reads carry no parameters; answers are what the table says
        if c.is_read:
            assert c.request_len == 3 and 4 <= c.reply_len <= 7


@settings(max_examples=200, deadline=None)
@given(
    servo_id=st.integers(0, 254),
    code=st.sampled_from(sorted(C.COMMANDS)),
    data=st.data(),
)
def test_round_trip_every_command(servo_id, code, data):
    cmd = C.COMMANDS[code]
    fields = struct.unpack(cmd.params, bytes(struct.calcsize(cmd.params)))
    values = []
    for ch in cmd.params[1:]:
        lim = {"B": (0, 255), "b": (-128, 127), "H": (0, 65535), "h": (-32768, 32767)}[ch]
        values.append(data.draw(st.integers(*lim)))
    assert len(values) == len(fields)
    raw = encode_request(servo_id, cmd, *values)
    pkt = decode(raw)
    assert pkt == Packet(servo_id, code, raw[5:-1])
    assert pkt.request_values() == tuple(values)
    assert raw[3] == len(raw) - 3 and raw[-1] == checksum(raw[2], raw[3], raw[4], raw[5:-1])


@settings(max_examples=200, deadline=None)
@given(params=st.binary(max_size=4), servo_id=st.integers(0, 253), cmd=st.integers(0, 255), flip=st.data())
def test_any_single_corruption_is_detected(params, servo_id, cmd, flip):
    raw = bytearray(encode(servo_id, cmd, params))
    k = flip.draw(st.integers(4, len(raw) - 1))  # CMD, params or CHK
    raw[k] ^= flip.draw(st.integers(1, 255))
    with pytest.raises(ChecksumError):
        decode(bytes(raw))


@settings(max_examples=200, deadline=None)
@given(
    garbage=st.lists(st.binary(max_size=12), min_size=2, max_size=2),
    positions=st.lists(st.integers(-100, 1100), min_size=1, max_size=5),
    chunk=st.integers(1, 9),
)
def test_resync_after_garbage(garbage, positions, chunk):
    """Garbage (even with 55 55 in it) before and between answers never hides a valid packet."""
    good = [encode_reply(i + 1, C.POS_READ, p) for i, p in enumerate(positions)]
    stream = garbage[0] + b"\x55\x55" + good[0] + garbage[1] + b"".join(good[1:])
    dec = StreamDecoder()
    got = []
    for k in range(0, len(stream), chunk):
        got += dec.feed(stream[k : k + chunk])
    valid = [p for p in got if p.cmd == C.POS_READ.code and len(p.params) == 2]
    # every real answer is found, in order (garbage may decode to stray packets only by a 1-in-256 checksum fluke)
    ids = [p.servo_id for p in valid]
    expected = list(range(1, len(positions) + 1))
    it = iter(ids)
    assert all(i in it for i in expected)
    assert [p.reply_values()[0] for p in valid if p.servo_id in expected][-len(positions) :] == positions


def test_noisy_stream_counts_checksum_errors():
    good = encode_reply(4, C.TEMP_READ, 41)
    bad = bytearray(good)
    bad[-1] ^= 0xFF
    dec = StreamDecoder()
    out = dec.feed(b"\x00\x55" + bytes(bad) + b"\x55\x55\x55" + good)
    assert [p.reply_values() for p in out] == [(41,)]
    assert dec.checksum_errors >= 1 and dec.skipped_bytes > 0  # false starts on 55 55 55 count too


def test_decode_rejects_malformed():
    with pytest.raises(ProtocolError, match="header"):
        decode(b"\x54\x55\x01\x03\x1c\xdf")
    with pytest.raises(ProtocolError, match="length"):
        decode(b"\x55\x55\x01\x04\x1c\xdf")
    with pytest.raises(ProtocolError, match="expected 2 parameter bytes"):
        Packet(1, C.POS_READ.code, b"\x01").reply_values()
    with pytest.raises(ValueError):
        encode(255, 1)
