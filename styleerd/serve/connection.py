"""The server's WebSocket connection: websockets' own, with each message handed over as it is
parsed, and replies written as they are made.

websockets' asyncio connection queues every message for a task to ``recv``, and its ``send`` is a
coroutine: a live stream's frame then costs two task wake-ups and two queues on the server, most
of what a frame costs outside the network at 200 single-stream clients (docs/DEPLOY.md, "The
protocol's cost"). Here, once a stream is open (``deliver_to``), each message goes straight to
its handler from websockets' parser, in order, and ``send_now`` frames a reply and writes it to
the socket at once. Before that (a hello, a viewer's or an upload's messages), ``next_message``
waits for them in order, with the same flow control as websockets' queue.

websockets' parser (a generator per frame, about 2.5 us a message here) and its framing of a reply
(0.8 us) were then a tenth of the protocol's cost. Once the handshake is done, frames are cut out of
the bytes here: a whole, masked, unfragmented data frame of an open connection goes to its handler
without that parser, and every other frame (pings, a close, fragments, anything malformed) is
handed whole to websockets, which handles it as before. Replies are framed here too.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable

from websockets.asyncio.server import ServerConnection
from websockets.frames import CloseCode, Frame, Opcode, apply_mask
from websockets.protocol import State

Message = bytes | str


class MessageConnection(ServerConnection):
    """A server connection whose messages go to ``on_message`` as they are parsed once it is set
    (``deliver_to``), and wait for ``next_message`` until then."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.on_message: Callable[[Message], None] | None = None
        self.inbox: deque[Message] = deque()  # messages parsed before ``on_message`` was set
        self.waiter: asyncio.Future | None = None  # ``next_message`` waiting for one
        self.parts: list[bytes] = []  # a fragmented message's frames so far
        self.text = False  # whether the message being assembled is text
        self.paused = False  # reading paused: ``max_queue_high`` messages wait
        self.failed = False  # a message broke the protocol: nothing after it is taken
        self.framing = False  # frames are cut out here (``_take_frames``), not by websockets' parser
        self.rest = bytearray()  # the start of a frame whose bytes have not all come
        self.needed = 0  # the bytes of that frame, where its header has come

    def data_received(self, data: bytes) -> None:
        if self.framing:
            return self._take_frames(data)
        handshake = self.request is None
        super().data_received(data)
        # websockets' parser stands at a frame's start once it has read the request and nothing after it
        if handshake and self.request is not None and not self.protocol.reader.buffer and not self.protocol.extensions:
            self.framing = True

    def _take_frames(self, data: bytes) -> None:
        """Whole frames out of ``data`` (after what was left of the last call): simple data frames
        to ``on_message``, every other frame whole to websockets' parser, which therefore always
        stands at a frame's start. Once the connection is not open, the parser takes everything."""
        if self.rest:  # extended in place: a frame sent a byte at a time costs no more than at once
            self.rest += data
            if len(self.rest) < self.needed:
                return
            data, self.rest = bytes(self.rest), bytearray()
        buf, at, end, protocol = data, 0, len(data), self.protocol
        self.needed = 0  # until a header says more
        while end - at >= 2:
            if protocol.state is not State.OPEN:
                self.framing = False
                return super().data_received(buf[at:])
            first, second = buf[at], buf[at + 1]
            size, head = second & 0x7F, 2
            if size == 126:
                size, head = int.from_bytes(buf[at + 2 : at + 4], "big"), 4
            elif size == 127:
                size, head = int.from_bytes(buf[at + 2 : at + 10], "big"), 10
            if end - at < head:
                break
            head += 4 if second & 0x80 else 0
            if size > (protocol.max_message_size or size) or size > (protocol.max_fragment_size or size):
                self.framing = False  # too big: websockets' parser refuses it (1009) without waiting for it
                return super().data_received(buf[at:])
            if end - at < head + size:
                self.needed = head + size
                break
            frame, at = buf[at : at + head + size], at + head + size
            opcode = first & 0x0F
            simple = first & 0xF0 == 0x80 and second & 0x80 and opcode in (1, 2)  # fin, no rsv, masked, data
            if not simple or self.on_message is None or protocol.current_size is not None:
                super().data_received(frame)
                continue
            message: Message = apply_mask(frame[head:], frame[head - 4 : head])
            if opcode == 1:
                try:
                    message = message.decode()
                except UnicodeDecodeError:
                    super().data_received(frame)  # refused there, as any other
                    continue
            self.on_message(message)
        self.rest = bytearray(buf[at:])

    def process_event(self, event) -> None:
        if not isinstance(event, Frame) or event.opcode not in (Opcode.TEXT, Opcode.BINARY, Opcode.CONT):
            return super().process_event(event)  # the opening handshake, pings and pongs
        if self.failed:
            return
        if event.opcode is not Opcode.CONT:  # the protocol checks continuations follow a first frame
            self.parts, self.text = [], event.opcode is Opcode.TEXT
        self.parts.append(event.data)
        if not event.fin:
            return
        data = self.parts[0] if len(self.parts) == 1 else b"".join(self.parts)
        self.parts = []
        if self.text:
            try:
                message: Message = data.decode()
            except UnicodeDecodeError:
                self.protocol.fail(CloseCode.INVALID_DATA, "a text message that is not UTF-8")
                self.send_data()
                self.failed = True
                return
        else:
            message = bytes(data)
        if self.on_message is not None:
            self.on_message(message)
            return
        self.inbox.append(message)
        if self.max_queue_high is not None and len(self.inbox) >= self.max_queue_high and not self.paused:
            self.transport.pause_reading()
            self.paused = True
        self._wake()

    def connection_lost(self, exc: Exception | None) -> None:
        super().connection_lost(exc)
        self._wake()

    def _wake(self) -> None:
        if self.waiter is not None and not self.waiter.done():
            self.waiter.set_result(None)

    async def next_message(self) -> Message:
        """The next message, in order; ``ConnectionClosed`` once the connection is closed and none is left."""
        while not self.inbox:
            if self.protocol.state is State.CLOSED:
                raise self.protocol.close_exc
            self.waiter = asyncio.get_running_loop().create_future()
            await self.waiter
        message = self.inbox.popleft()
        if self.paused and len(self.inbox) <= (self.max_queue_low or (self.max_queue_high or 4) // 4):
            self.transport.resume_reading()
            self.paused = False
        return message

    def deliver_to(self, on_message: Callable[[Message], None]) -> None:
        """From now on each message goes to ``on_message`` as it is parsed (which must not raise);
        those already waiting go first, in order."""
        while self.inbox:
            on_message(self.inbox.popleft())
        self.on_message = on_message
        if self.paused:
            self.transport.resume_reading()
            self.paused = False


def send_now(ws: MessageConnection, message: Message, backlog: int) -> bool:
    """Frame ``message`` and write it to the socket now (no task, no queue). False where more than
    ``backlog`` bytes are still unsent (a client that does not read); nothing is sent then. A
    closing connection takes nothing and says True: its end is handled where it closes."""
    if ws.protocol.state is not State.OPEN:
        return True
    if ws.transport.get_write_buffer_size() > backlog:
        return False
    if ws.protocol.writes:  # a pong or the like first, in order
        ws.send_data()
    data, opcode = (message.encode(), 0x81) if isinstance(message, str) else (message, 0x82)
    n = len(data)
    if n < 126:
        head = bytes((opcode, n))
    elif n < 65536:
        head = bytes((opcode, 126)) + n.to_bytes(2, "big")
    else:
        head = bytes((opcode, 127)) + n.to_bytes(8, "big")
    ws.transport.write(head + data)
    return True
