"""HTTP/2 framing for gRPC, shared by the load generator's client and the server's own transport.

RFC 9113's frames, as much of them as gRPC uses: the 9-byte frame header,
SETTINGS entries, header blocks (HEADERS and CONTINUATION, padding and
priority stripped; HPACK itself is the ``hpack`` library's) and gRPC's
length-prefixed messages (a flag byte, a big-endian 4-byte length, the
protobuf bytes). Pure Python, no I/O: :mod:`caveclod.client.h2wire` and
:mod:`caveclod.server.h2server` read and write through asyncio protocols.
"""

from __future__ import annotations

from typing import Iterator

PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"
# Frame types and flags (RFC 9113, section 6).
DATA, HEADERS, PRIORITY, RST_STREAM, SETTINGS, PUSH_PROMISE, PING, GOAWAY, WINDOW_UPDATE, CONTINUATION = range(10)
END_STREAM, ACK, END_HEADERS, PADDED, PRIORITY_FLAG = 0x1, 0x1, 0x4, 0x8, 0x20
SETTINGS_HEADER_TABLE_SIZE, SETTINGS_ENABLE_PUSH, SETTINGS_MAX_CONCURRENT_STREAMS = 1, 2, 3
SETTINGS_INITIAL_WINDOW_SIZE, SETTINGS_MAX_FRAME_SIZE = 4, 5
NO_ERROR, PROTOCOL_ERROR, INTERNAL_ERROR, FLOW_CONTROL_ERROR = 0x0, 0x1, 0x2, 0x3
REFUSED_STREAM, CANCEL, ENHANCE_YOUR_CALM, INADEQUATE_SECURITY = 0x7, 0x8, 0xB, 0xC
MAX_STREAM_ID = (1 << 31) - 1
DEFAULT_WINDOW = 65535
DEFAULT_FRAME = 16384
MAX_HEADER_BLOCK = 256 << 10     # a header block past this (HPACK decodes at most 64 KiB of headers) is an attack


class ProtocolViolation(Exception):
    """The peer broke HTTP/2: the connection is over (one line saying how)."""


class MessageError(Exception):
    """A gRPC message that cannot be taken: ``kind`` is "compressed" or "too large"."""

    def __init__(self, kind: str, details: str):
        super().__init__(details)
        self.kind = kind


def frame(kind: int, flags: int, stream_id: int, payload: bytes = b"") -> bytes:
    """One frame: the 9-byte header (24-bit length, type, flags, 31-bit stream id) and the payload."""
    return len(payload).to_bytes(3, "big") + bytes((kind, flags)) + stream_id.to_bytes(4, "big") + payload


def settings_frame(entries) -> bytes:
    """A SETTINGS frame of (identifier, value) pairs."""
    return frame(SETTINGS, 0, 0, b"".join(k.to_bytes(2, "big") + v.to_bytes(4, "big") for k, v in entries))


def window_update(stream_id: int, amount: int) -> bytes:
    return frame(WINDOW_UPDATE, 0, stream_id, amount.to_bytes(4, "big"))


def goaway(last_stream_id: int, code: int) -> bytes:
    return frame(GOAWAY, 0, 0, last_stream_id.to_bytes(4, "big") + code.to_bytes(4, "big"))


def header_frames(block: bytes, stream_id: int, end_stream: bool, max_frame: int) -> bytes:
    """An HPACK header block as a HEADERS frame and as many CONTINUATIONs as ``max_frame`` asks."""
    first, rest = block[:max_frame], block[max_frame:]
    out = frame(HEADERS, (END_STREAM if end_stream else 0) | (0 if rest else END_HEADERS), stream_id, first)
    while rest:
        piece, rest = rest[:max_frame], rest[max_frame:]
        out += frame(CONTINUATION, 0 if rest else END_HEADERS, stream_id, piece)
    return out


def message(data: bytes) -> bytes:
    """One gRPC message as it travels: flag 0 (not compressed), length, bytes."""
    return b"\x00" + len(data).to_bytes(4, "big") + data


class FrameReader:
    """Cuts the bytes read from a socket into frames, whatever the reads' boundaries."""

    def __init__(self, max_frame: int):
        self.max_frame = max_frame        # the SETTINGS_MAX_FRAME_SIZE we told the peer
        self._rest = b""

    def frames(self, data: bytes) -> Iterator[tuple[int, int, int, bytes]]:
        """(type, flags, stream id, payload) of every whole frame in what has been read so far.

        Raises ProtocolViolation for a frame longer than ``max_frame``. A
        reader stopped before the end (a broken connection) is not used again.
        """
        buf = self._rest + data if self._rest else data
        pos, end = 0, len(buf)
        while end - pos >= 9:
            length = buf[pos] << 16 | buf[pos + 1] << 8 | buf[pos + 2]
            if length > self.max_frame:
                raise ProtocolViolation(f"a frame of {length} bytes (at most {self.max_frame}, as our SETTINGS say)")
            if end - pos - 9 < length:
                break
            kind, flags = buf[pos + 3], buf[pos + 4]
            stream_id = (buf[pos + 5] << 24 | buf[pos + 6] << 16 | buf[pos + 7] << 8 | buf[pos + 8]) & MAX_STREAM_ID
            start, pos = pos + 9, pos + 9 + length
            yield kind, flags, stream_id, buf[start:pos]
        self._rest = buf[pos:]              # a frame cut by the read: the next read completes it


def parse_settings(payload: bytes) -> list[tuple[int, int]]:
    """The (identifier, value) entries of a SETTINGS frame's payload."""
    if len(payload) % 6:
        raise ProtocolViolation(f"a SETTINGS frame of {len(payload)} bytes (not whole 6-byte entries)")
    return [(int.from_bytes(payload[i:i + 2], "big"), int.from_bytes(payload[i + 2:i + 6], "big"))
            for i in range(0, len(payload), 6)]


class PeerSettings:
    """What the peer's SETTINGS say that our end must keep: the initial window of new streams (ours to
    send on), the largest frame we may send it, and how many streams it lets us open."""

    __slots__ = ("window", "frame", "streams")

    def __init__(self):
        self.window, self.frame, self.streams = DEFAULT_WINDOW, DEFAULT_FRAME, MAX_STREAM_ID

    def apply(self, payload: bytes, encoder) -> int:
        """Take a SETTINGS frame's entries (the HPACK table size into ``encoder``, an ``hpack.Encoder``);
        the change of the initial stream window, which applies to the streams already open too.
        Raises ProtocolViolation for a value out of range."""
        delta = 0
        for key, value in parse_settings(payload):
            if key == SETTINGS_HEADER_TABLE_SIZE:
                encoder.header_table_size = value
            elif key == SETTINGS_MAX_CONCURRENT_STREAMS:
                self.streams = value
            elif key == SETTINGS_INITIAL_WINDOW_SIZE:
                if value > MAX_STREAM_ID:
                    raise ProtocolViolation(f"an initial window of {value} bytes")
                delta += value - self.window
                self.window = value
            elif key == SETTINGS_MAX_FRAME_SIZE:
                if not DEFAULT_FRAME <= value <= (1 << 24) - 1:
                    raise ProtocolViolation(f"a maximum frame size of {value}")
                self.frame = value
        return delta


def data_payload(flags: int, payload: bytes) -> bytes:
    """A DATA frame's data, its padding stripped."""
    if flags & PADDED:
        if not payload or payload[0] >= len(payload):
            raise ProtocolViolation("a DATA frame whose padding is longer than the frame")
        return payload[1:len(payload) - payload[0]]
    return payload


class HeaderBlocks:
    """Joins a HEADERS frame and its CONTINUATIONs into one header block (at most MAX_HEADER_BLOCK bytes)."""

    def __init__(self):
        self.open: tuple | None = None          # (stream id, END_STREAM, fragments) of a block in progress
        self._size = 0

    def add(self, kind: int, flags: int, stream_id: int, payload: bytes) -> tuple[int, bool, bytes] | None:
        """(stream id, END_STREAM, the whole block) once END_HEADERS comes; None before."""
        if kind == CONTINUATION:
            if self.open is None or self.open[0] != stream_id:
                raise ProtocolViolation("a CONTINUATION that continues no header block")
            _, ends, fragments = self.open
        else:
            if stream_id == 0:
                raise ProtocolViolation("a HEADERS frame on stream 0")
            ends, fragments = bool(flags & END_STREAM), []
            start, stop = 0, len(payload)
            if flags & PADDED:
                if not payload or payload[0] >= len(payload):
                    raise ProtocolViolation("a HEADERS frame whose padding is longer than the frame")
                start, stop = 1, len(payload) - payload[0]
            if flags & PRIORITY_FLAG:
                start += 5
            if start > stop:
                raise ProtocolViolation("a HEADERS frame shorter than its padding and priority")
            payload = payload[start:stop]
            self._size = 0
        self._size += len(payload)
        if self._size > MAX_HEADER_BLOCK:
            raise ProtocolViolation(f"a header block of more than {MAX_HEADER_BLOCK} bytes")
        fragments.append(payload)
        if not flags & END_HEADERS:
            self.open = (stream_id, ends, fragments)
            return None
        self.open = None
        return stream_id, ends, b"".join(fragments)


class Messages:
    """Cuts a stream's DATA into gRPC messages, whatever the frames' boundaries."""

    __slots__ = ("max_message", "_buf")

    def __init__(self, max_message: int):
        self.max_message = max_message
        self._buf = bytearray()

    @property
    def partial(self) -> int:
        """Bytes of a message begun and not finished."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[bytes]:
        """The messages ``data`` completes. Raises MessageError for a compressed or too large one."""
        buf = self._buf
        if not buf and len(data) >= 5 and not data[0] and int.from_bytes(data[1:5], "big") == len(data) - 5:
            return [data[5:]]                   # the usual case: one whole message in one frame
        buf += data
        out, start = [], 0
        while len(buf) - start >= 5:
            size = int.from_bytes(buf[start + 1:start + 5], "big")
            if buf[start]:
                raise MessageError("compressed", "a compressed message (none was asked for)")
            if size > self.max_message:
                raise MessageError("too large", f"a message of {size} bytes (at most {self.max_message})")
            if len(buf) - start - 5 < size:
                break
            out.append(bytes(buf[start + 5:start + 5 + size]))
            start += 5 + size
        if start:
            del buf[:start]
        return out
