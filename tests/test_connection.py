"""The server connection's own framing (serve.connection) against websockets' parser: the same
bytes, cut anywhere, give the same messages in the same order, the same replies on the wire
(pongs, closes) and the same end, whether frames are cut out by ``_take_frames`` or parsed by
websockets alone."""

from __future__ import annotations

import asyncio
import itertools
import os
import struct
from types import SimpleNamespace

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from websockets.protocol import State
from websockets.server import ServerProtocol

from styleerd.serve.connection import MessageConnection, send_now

MAX_SIZE = 200
REQUEST = (
    b"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
    b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
)


class Transport:
    """What the connection writes, in order; reading paused or not."""

    def __init__(self) -> None:
        self.out: list[bytes] = []
        self.paused = False

    def write(self, data: bytes) -> None:
        self.out.append(bytes(data))

    def write_eof(self) -> None:
        self.out.append(b"<eof>")

    def can_write_eof(self) -> bool:
        return True

    def get_write_buffer_size(self) -> int:
        return 0

    def set_write_buffer_limits(self, high=None, low=None) -> None:
        pass

    def pause_reading(self) -> None:
        self.paused = True

    def resume_reading(self) -> None:
        self.paused = False

    def is_closing(self) -> bool:
        return False

    def close(self) -> None:
        self.out.append(b"<close>")

    def abort(self) -> None:
        self.out.append(b"<abort>")

    def get_extra_info(self, name, default=None):
        return default


def opened(own_framing: bool) -> tuple[MessageConnection, Transport]:
    """A connection past its opening handshake, as websockets' server leaves it."""
    server = SimpleNamespace(handler=lambda conn: asyncio.sleep(0), handler_tasks=set())  # no handler: the test reads
    conn = MessageConnection(ServerProtocol(max_size=MAX_SIZE), server=server, ping_interval=None)
    transport = Transport()
    conn.connection_made(transport)
    conn.data_received(REQUEST)
    conn.protocol.send_response(conn.protocol.accept(conn.request))
    conn.send_data()
    assert conn.protocol.state is State.OPEN and conn.framing
    conn.framing = own_framing
    transport.out.clear()
    return conn, transport


def wire(opcode: int, payload: bytes, fin: bool = True, masked: bool = True, rsv: int = 0) -> bytes:
    """One client frame (RFC 6455) as given, lengths in every encoding."""
    n = len(payload)
    size = bytes([n]) if n < 126 else bytes([126]) + struct.pack(">H", n) if n < 65536 else bytes([127]) + n.to_bytes(8)
    head = bytes([(0x80 if fin else 0) | rsv << 4 | opcode, size[0] | (0x80 if masked else 0)]) + size[1:]
    if not masked:
        return head + payload
    mask = os.urandom(4)
    return head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def run(chunks: list[bytes], deliver_at: int, own_framing: bool) -> tuple:
    """Feed ``chunks`` in turn, handing messages over from the chunk at ``deliver_at`` on (those
    before wait in the connection's inbox); what came out, the state and the close sent."""

    async def main():
        conn, transport = opened(own_framing)
        got: list = []
        for i, chunk in enumerate(chunks):
            if i == deliver_at:
                conn.deliver_to(got.append)
            conn.data_received(chunk)
        if deliver_at >= len(chunks):
            conn.deliver_to(got.append)
        close = conn.protocol.close_sent
        return got, conn.protocol.state, close and (close.code, close.reason), b"".join(transport.out)

    return asyncio.run(main())


payloads = st.sampled_from(
    [b"", b"x" * 125, b"y" * 126, b"z" * 180, b"w" * (MAX_SIZE + 1), "é".encode(), b"\xff\xfe", b'{"a": 1}']
) | st.binary(max_size=40)
frames = st.tuples(
    st.sampled_from([0x0, 0x1, 0x2, 0x3, 0x8, 0x9, 0xA]),
    payloads,
    st.booleans(),  # fin
    st.sampled_from([True] * 9 + [False]),  # masked
    st.sampled_from([0] * 9 + [4]),  # rsv1
)


@settings(max_examples=1000, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(st.lists(frames, max_size=8), st.lists(st.integers(0, 2000), max_size=30), st.integers(0, 9))
@example([(0x2, b"a", False, True, 0), (0x2, b"b", True, True, 0)], [], 0)  # a message inside a fragmented one
@example([(0x2, b"w" * (MAX_SIZE + 1), True, True, 0)], [5], 0)  # too big: refused before it has all come
@example([(0x1, b"a", False, True, 0), (0x9, b"", True, True, 0), (0x0, b"b", True, True, 0)], [3, 9], 0)
def test_own_framing_takes_the_bytes_as_websockets_parser_does(sent, cuts, deliver_after):
    """The oracle is websockets' parser given one whole frame at a time (given several at once, it
    reads them all before handing any over, so which of a bad message and a close behind it ends
    the connection depends on how the bytes were cut). The own framing gets them cut anywhere."""
    whole = [wire(op, p, fin, masked, rsv) for op, p, fin, masked, rsv in sent]
    whole.append(wire(0x8, struct.pack(">H", 1000) + b"bye"))
    data, deliver_after = b"".join(whole), min(deliver_after, len(whole))
    handover = sum(len(w) for w in whole[:deliver_after])  # messages are handed over from this byte on
    at = sorted({min(c, len(data)) for c in cuts} | {0, handover, len(data)})
    chunks = [data[a:b] for a, b in itertools.pairwise(at)]
    assert run(chunks, at.index(handover), True) == run(whole, deliver_after, False)


def test_byte_by_byte_messages_and_a_ping_between_them():
    """Every byte on its own: the messages come whole and in order, the ping's pong goes out, and a
    text message that is not UTF-8 closes the connection with 1007, as websockets does."""
    whole = [wire(0x2, b"\x01" * 130), wire(0x9, b"p"), wire(0x1, "héllo".encode()), wire(0x1, b"\xff")]
    whole.append(wire(0x2, b"after"))
    got, state, close, out = run([bytes([b]) for b in b"".join(whole)], 0, True)
    assert got == [b"\x01" * 130, "héllo"] and close == (1007, "a text message that is not UTF-8")
    assert out.startswith(b"\x8a\x01p") and state is State.CLOSING
    assert (got, state, close, out) == run(whole, 0, False)


def test_replies_are_framed_as_websockets_frames_them():
    """``send_now``'s frames, every length encoding, are websockets' own bytes."""

    async def main():
        for message in [b"", b"a" * 125, b"b" * 126, b"c" * 70000, "text é"]:
            conn, transport = opened(True)
            assert send_now(conn, message, 1 << 20)
            ref = ServerProtocol()
            ref.state = State.OPEN
            if isinstance(message, str):
                ref.send_text(message.encode())
            else:
                ref.send_binary(message)
            assert b"".join(transport.out) == b"".join(ref.data_to_send()), len(message)

    asyncio.run(main())
