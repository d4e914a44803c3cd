"""Framing of Leica emScon TPI, binary C variant (TCP port 700): the packet header, the two directions, the entry
points that turn one packet into a message and back, and the stream framer client and mock server share.

Frame: every packet starts with PacketHeaderT {int32 lPacketSize (whole packet, bytes); int32 type
(ES_DataType)}, little-endian [H] (beckjac/emscon_ros include/emscon_ros/ES_C_API_Def.h, V3.6).

  [K]  shohty/Leica_KEK  CESAPI/packet.py  (CESAPI Python client): PacketHeaderT packed as '<i I' (8 bytes):
       `long` is 32 bits on the wire (the header is written for MSVC, where long is 32 bits; [H] even
       `#define long int32_t` for this reason).
       MuffinSpawn/Leica's CESAPI packs lPacketSize in 4 bytes too at its current head (its CESAPI/sniff.py
       frames `PACKET_HEADER_SIZE = 8  # lPacketSize, type`); only early commits of its CESAPI/packet.py,
       generated on 64-bit Linux, packed it as '<q' (a 12-byte header).

Command requests and their answers share ES_DT_Command and the command id and are told apart only by direction,
so `decode_packet` takes the direction (drivers/emscon/messages.py holds both sides' layouts).

`decode_packet` is total: for any bytes it returns a message or raises ProtocolError (fuzzed in
tests/test_emscon_codec.py).  `PacketReader` frames a byte stream into packets and never buffers more than one
packet of at most MAX_PACKET_BYTES plus the chunk being fed.
"""

from __future__ import annotations

import enum
import struct

from trackcal.drivers.emscon.enums import DataType, enum_value
from trackcal.drivers.emscon.messages import (
    Message,
    Request,
    decode_from_tracker,
    decode_request,
    encode_command,
    encode_from_tracker,
)
from trackcal.drivers.errors import ProtocolError

HEADER = struct.Struct("<ii")  # PacketHeaderT {long lPacketSize; enum ES_DataType type}  [H], [K]
HEADER_SIZE = HEADER.size  # 8
# The largest struct of the V3.6 header is a few hundred bytes (e.g. GetCompensations2RT with its UNICODE
# strings); 64 KiB is a sane cap that still rejects a corrupted size field before any allocation.
MAX_PACKET_BYTES = 64 * 1024
_COMMAND_ID = struct.Struct("<i")  # BasicCommandCT's ES_Command, after the header [H]


class Direction(enum.Enum):
    TO_TRACKER = "client -> tracker"  # command requests (*CT structs)
    FROM_TRACKER = "tracker -> client"  # answers (*RT), errors, results, status changes


def encode(message: Message) -> bytes:
    """The bytes of any message, in its own direction (requests -> tracker, everything else -> client)."""
    if isinstance(message, Request):
        return encode_command(message)
    return encode_from_tracker(message)


def decode_packet(buf: bytes, direction: Direction = Direction.FROM_TRACKER) -> Message:
    """Decode one complete packet, or raise ProtocolError. `direction` tells requests from answers."""
    if not isinstance(buf, bytes | bytearray | memoryview):
        raise ProtocolError(f"expected bytes, got {type(buf).__name__}")
    buf = bytes(buf)
    if len(buf) < HEADER_SIZE:
        raise ProtocolError(f"packet of {len(buf)} bytes is shorter than the {HEADER_SIZE}-byte PacketHeaderT")
    size, type_value = HEADER.unpack_from(buf)
    if size != len(buf):
        raise ProtocolError(f"lPacketSize says {size} bytes but the packet has {len(buf)}")
    data_type = enum_value(DataType, type_value, "PacketHeaderT.type")
    if direction == Direction.TO_TRACKER:
        if data_type != DataType.COMMAND:
            raise ProtocolError(f"a client sends only command packets, not {data_type.name}")
        return decode_request(buf)
    return decode_from_tracker(buf, data_type)


def packet_ids(packet: bytes) -> tuple[int, int | None]:
    """The raw PacketHeaderT.type of a framed packet and, when it is long enough for BasicCommandCT, the command id
    after the header (None otherwise), unchecked: what a server answers a packet it cannot decode with."""
    if len(packet) < HEADER_SIZE:
        raise ValueError(f"a framed packet holds at least the {HEADER_SIZE}-byte header, got {len(packet)} bytes")
    _, data_type = HEADER.unpack_from(packet)
    if len(packet) < HEADER_SIZE + _COMMAND_ID.size:
        return data_type, None
    return data_type, _COMMAND_ID.unpack_from(packet, HEADER_SIZE)[0]


# -------------------- framing
class PacketReader:
    """Stream framer: feed(bytes) -> the complete packets so far (each still to be decoded).

    Survives partial reads and several packets per read. A size field below the header size or above
    `max_packet_bytes` raises ProtocolError at once (before buffering the body); the stream cannot be
    resynchronised after that, so the reader stays failed and the caller should drop the connection.
    """

    def __init__(self, max_packet_bytes: int = MAX_PACKET_BYTES) -> None:
        if max_packet_bytes < HEADER_SIZE:
            raise ValueError("max_packet_bytes must hold at least a header")
        self.max_packet_bytes = max_packet_bytes
        self._buf = bytearray()
        self._failed: str | None = None

    @property
    def pending(self) -> int:
        """Bytes received but not yet part of a complete packet."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[bytes]:
        if self._failed is not None:
            raise ProtocolError(f"stream already out of sync: {self._failed}")
        self._buf += data
        packets: list[bytes] = []
        while len(self._buf) >= 4:
            (size,) = struct.unpack_from("<i", self._buf, 0)
            if size < HEADER_SIZE or size > self.max_packet_bytes:
                self._failed = f"lPacketSize {size} outside {HEADER_SIZE}..{self.max_packet_bytes} bytes"
                self._buf.clear()
                raise ProtocolError(self._failed)
            if len(self._buf) < size:
                break
            packets.append(bytes(self._buf[:size]))
            del self._buf[:size]
        return packets
