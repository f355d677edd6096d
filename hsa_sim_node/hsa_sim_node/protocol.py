"""Dynamixel Protocol 2.0 packet codec (no ROS): CRC, byte stuffing, packet encoding and stream
reassembly.

Framing, instruction and error codes follow the ROBOTIS e-Manual, Protocol 2.0 page. Used by the
emulated MX-28 bus (:mod:`hsa_sim_node.mx28_emulator`) to read instruction packets and write status
packets.
"""

from __future__ import annotations

from dataclasses import dataclass

# Protocol 2.0 framing and instruction set.
HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REBOOT = 0x08
INST_CLEAR = 0x10
INST_STATUS = 0x55
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83
INST_BULK_READ = 0x92

# Status packet error field: bit 7 is the hardware alert, bits 0-6 the error number.
ERRBIT_ALERT = 0x80
ERR_RESULT_FAIL = 0x01
ERR_INSTRUCTION = 0x02
ERR_CRC = 0x03
ERR_DATA_RANGE = 0x04
ERR_DATA_LENGTH = 0x05
ERR_DATA_LIMIT = 0x06
ERR_ACCESS = 0x07

_MAX_PACKET_LENGTH = 1024  # longest Length field accepted before resynchronising on the next header


def _make_crc_table() -> tuple[int, ...]:
    """Table of the non-reflected CRC-16 with polynomial 0x8005 and initial value 0 used by Protocol
    2.0."""
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _make_crc_table()


def crc16(data: bytes | bytearray) -> int:
    """Protocol 2.0 CRC of ``data`` (header to last parameter, stuffing included)."""
    crc = 0
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes | bytearray) -> bytes:
    """Byte-stuff instruction+parameters: every 0xFF 0xFF 0xFD gets an extra 0xFD so it cannot look
    like a header."""
    if HEADER[:3] not in body:
        return bytes(body)
    out = bytearray()
    for i, byte in enumerate(body):
        out.append(byte)
        if byte == 0xFD and i >= 2 and body[i - 1] == 0xFF and body[i - 2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes | bytearray) -> bytes:
    """Undo :func:`stuff`: 0xFF 0xFF 0xFD 0xFD becomes 0xFF 0xFF 0xFD."""
    if HEADER[:3] not in body:
        return bytes(body)
    out = bytearray()
    i = 0
    while i < len(body):
        byte = body[i]
        out.append(byte)
        stuffed = byte == 0xFD and i >= 2 and body[i - 1] == 0xFF and body[i - 2] == 0xFF
        i += 2 if stuffed and i + 1 < len(body) and body[i + 1] == 0xFD else 1
    return bytes(out)


def encode_packet(dxl_id: int, instruction: int, params: bytes | bytearray = b"") -> bytes:
    """Complete Protocol 2.0 packet (header, ID, length, stuffed instruction+params, CRC)."""
    body = stuff(bytes([instruction]) + bytes(params))
    length = len(body) + 2
    head = HEADER + bytes([dxl_id, length & 0xFF, length >> 8])
    crc = crc16(head + body)
    return head + body + bytes([crc & 0xFF, crc >> 8])


def u16(data: bytes, offset: int) -> int:
    """Little-endian unsigned 16-bit field of ``data`` at ``offset`` (addresses and lengths in
    parameters)."""
    return data[offset] | data[offset + 1] << 8


@dataclass(frozen=True)
class Packet:
    """One received packet, already unstuffed; ``crc_ok`` is False when the CRC did not match."""

    dxl_id: int
    instruction: int
    params: bytes
    crc_ok: bool


class PacketReader:
    """Reassembles packets from a byte stream: header search, length, CRC check, unstuffing."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def __len__(self) -> int:
        return len(self._buffer)

    def feed(self, data: bytes) -> None:
        """Append received bytes."""
        self._buffer += data

    def clear(self) -> None:
        """Drop buffered bytes (a partial packet whose remainder never came)."""
        self._buffer.clear()

    def next_packet(self) -> Packet | None:
        """Next complete packet, or None until more bytes arrive; malformed headers are skipped byte
        by byte."""
        buf = self._buffer
        while True:
            start = buf.find(HEADER[:3])
            if start < 0:
                del buf[: max(0, len(buf) - 2)]  # keep a possible partial header
                return None
            del buf[:start]
            if len(buf) < 7:
                return None
            dxl_id, length = buf[4], buf[5] | buf[6] << 8
            if buf[3] != 0x00 or dxl_id in (0xFD, 0xFF) or not 3 <= length <= _MAX_PACKET_LENGTH:
                del buf[0]
                continue
            if len(buf) < 7 + length:
                return None
            raw = bytes(buf[: 7 + length])
            del buf[: 7 + length]
            body = unstuff(raw[7:-2])
            crc_ok = crc16(raw[:-2]) == raw[-2] | raw[-1] << 8
            return Packet(dxl_id, body[0], body[1:], crc_ok)
