"""Requests and responses matched by sequence number, with timeouts and retries; streamed
record frames queued separately with loss detection from each stream's frame counter.

Synchronous and single-threaded: bytes are read only while a call waits, so no thread runs
behind the caller's back. Every request is preceded by a 0x00 so that a partial frame left on
the line (garbage, a cut cable) cannot swallow it.

Retries are safe for every request: a retry resends the very same bytes (same seq), and a
station answers a request identical to the last one it answered from memory, without running
it again (at-most-once, protocol/PROTOCOL.md "Retries"). The first seq of a client is drawn
from the operating system's random source, not from :mod:`random` (which callers may seed),
so a new client does not repeat the seqs, and thus the remembered last request, of an
earlier one.
"""

from __future__ import annotations

import collections
import secrets
import time
from dataclasses import dataclass
from typing import TypeVar

from uwbcal.errors import DeviceTimeout, ProtocolError
from uwbcal.link import proto_gen as pg
from uwbcal.link.framing import Frame, FrameDecoder, FrameError, encode_frame
from uwbcal.link.transport import Transport

R = TypeVar("R", bound=pg.Message)

#: Default time to wait for one response, s.
DEFAULT_TIMEOUT_S = 1.0
#: Default number of retries after the first attempt.
DEFAULT_RETRIES = 2


class ErrorResponse(ProtocolError):
    """The station answered a request with ERROR."""

    def __init__(self, port: str, request_type: int, err: pg.ErrorResp) -> None:
        self.code = err.code
        self.code_name = pg.ERROR_NAMES.get(err.code, f"code {err.code}")
        self.request_type = err.request_type or request_type
        self.detail = err.detail
        self.field = _field_name(self.request_type, err.code, err.detail)
        name = pg.MESSAGE_NAMES.get(self.request_type, f"type 0x{self.request_type:02X}")
        where = (
            f", field '{self.field}'"
            if self.field
            else (f", detail {err.detail}" if err.detail != pg.DETAIL_NONE else "")
        )
        doc = pg.ERROR_DOCS.get(err.code, "")
        super().__init__(
            f"{port}: {name} failed: {self.code_name}{where}" + (f" ({doc.split(';')[0]})" if doc else "")
        )


def _field_name(request_type: int, code: int, detail: int) -> str | None:
    if code != pg.ERR_BAD_VALUE:
        return None
    cls = pg.REQUESTS.get(request_type)
    if cls is None or detail >= len(cls.FIELDS):
        return None
    return cls.FIELDS[detail]


@dataclass(frozen=True)
class StreamFrame:
    """A streamed record frame. ``lost`` counts frames of this type missing just before it."""

    type: int
    seq: int
    payload: bytes
    lost: int = 0


class Client:
    """One station's link: ``request()`` for request/response, ``next_stream()`` for records."""

    def __init__(
        self,
        transport: Transport,
        *,
        timeout: float = DEFAULT_TIMEOUT_S,
        retries: int = DEFAULT_RETRIES,
        first_seq: int | None = None,
    ) -> None:
        self.transport = transport
        self.port = transport.port
        self.timeout = timeout
        self.retries = retries
        self._decoder = FrameDecoder()
        self._inbox: collections.deque[Frame | FrameError] = collections.deque()
        self._streams: collections.deque[StreamFrame] = collections.deque()
        self._stream_next: dict[int, int] = {}
        #: Frames lost per stream type since this client opened.
        self.stream_lost: dict[int, int] = collections.defaultdict(int)
        #: Frames per stream type that came again or late (behind the counter).
        self.stream_dup: dict[int, int] = collections.defaultdict(int)
        #: Frame errors and ERRORs with seq 0 received (the station could not read a frame).
        self.unattributed: list[FrameError | pg.ErrorResp] = []
        #: The seq last used; the first request gets the next one. Random unless given: see the
        #: module docstring.
        self._seq = first_seq if first_seq is not None else 1 + secrets.randbelow(0xFFFE)

    # ---- sending -------------------------------------------------------------------------
    def next_seq(self) -> int:
        """A fresh sequence number, never 0 (0 is reserved for unattributable errors)."""
        self._seq = self._seq % 0xFFFF + 1
        return self._seq

    def send_raw(self, data: bytes) -> None:
        """Write bytes as they are (tests send malformed frames this way)."""
        self.transport.write(data)

    def request(self, msg: pg.Request[R], *, timeout: float | None = None, retries: int | None = None) -> R:
        """Send a request, return its decoded response; ErrorResponse if the station says ERROR,
        DeviceTimeout when every attempt went unanswered."""
        frame = self.request_frame(msg.TYPE, msg.encode(), timeout=timeout, retries=retries)
        return msg.response_class().decode(frame.payload)

    def request_frame(
        self, type_: int, payload: bytes = b"", *, timeout: float | None = None, retries: int | None = None
    ) -> Frame:
        """Send a request of any type and return the response frame. A retry resends the same
        frame byte for byte (same seq), so a late answer to an earlier attempt is accepted and
        the station answers the retry of a request it already ran from memory (the request
        runs at most once). ``retries=0`` is for probes that should fail fast, not for safety."""
        timeout = self.timeout if timeout is None else timeout
        retries = self.retries if retries is None else retries
        seq = self.next_seq()
        data = b"\x00" + encode_frame(Frame(type=type_, seq=seq, payload=payload))
        for _attempt in range(retries + 1):
            self.transport.write(data)
            deadline = time.monotonic() + timeout
            while True:
                got = self._take_response(seq, type_)
                if got is not None:
                    return got
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._pump(left)
        name = pg.MESSAGE_NAMES.get(type_, f"type 0x{type_:02X}")
        raise DeviceTimeout(
            f"{self.port}: no answer to {name} after {retries + 1} attempt(s) of "
            f"{timeout:g} s each (is a station running on this port?)"
        )

    # ---- receiving -----------------------------------------------------------------------
    def read_frame(self, timeout: float) -> Frame | FrameError | None:
        """The next frame or frame error of any kind, unsorted (for tests), or None."""
        deadline = time.monotonic() + timeout
        while not self._inbox:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self._pump(left)
        return self._inbox.popleft()

    def next_stream(self, timeout: float) -> StreamFrame | None:
        """The next streamed record frame, or None after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while True:
            self._sort_inbox()
            if self._streams:
                return self._streams.popleft()
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self._pump(left)

    def expect_stream(self, type_: int, seq: int) -> None:
        """Declare the counter the next frame of stream ``type_`` must carry (the first frame
        seen otherwise sets it; station counters start at 0 when it boots)."""
        self._stream_next[type_] = seq & 0xFFFF

    def close(self) -> None:
        self.transport.close()

    # ---- internals -----------------------------------------------------------------------
    def _pump(self, wait_s: float) -> None:
        data = self.transport.read(min(wait_s, 0.2))
        if data:
            self._inbox.extend(self._decoder.feed(data))

    def _take_stream(self, f: Frame) -> None:
        exp = self._stream_next.get(f.type)
        lost = 0 if exp is None else (f.seq - exp) & 0xFFFF
        if lost >= 0x8000:
            # Behind the counter: a duplicated or late frame, not 65,535 lost ones. Its records
            # are still handed on (the recorder drops those it has).
            self.stream_dup[f.type] += 1
            self._streams.append(StreamFrame(f.type, f.seq, f.payload, 0))
            return
        if lost:
            self.stream_lost[f.type] += lost
        self._stream_next[f.type] = (f.seq + 1) & 0xFFFF
        self._streams.append(StreamFrame(f.type, f.seq, f.payload, lost))

    def _sort_inbox(self) -> None:
        """Move stream frames to their queue; drop what answers nothing we wait for."""
        keep: collections.deque[Frame | FrameError] = collections.deque()
        while self._inbox:
            item = self._inbox.popleft()
            if isinstance(item, FrameError):
                self.unattributed.append(item)
            elif item.is_stream and item.version == pg.PROTOCOL_VERSION:
                self._take_stream(item)
            else:
                keep.append(item)
        self._inbox = keep

    def _take_response(self, seq: int, type_: int) -> Frame | None:
        self._sort_inbox()
        while self._inbox:
            item = self._inbox.popleft()
            assert isinstance(item, Frame)
            if item.version != pg.PROTOCOL_VERSION:
                raise ProtocolError(
                    f"{self.port}: the station speaks protocol version {item.version}, this host "
                    f"version {pg.PROTOCOL_VERSION}: update the firmware or the host"
                )
            if item.type == pg.T_ERROR and item.is_response:
                err = pg.ErrorResp.decode(item.payload)
                if item.seq == seq:
                    raise ErrorResponse(self.port, type_, err)
                if item.seq == 0:
                    self.unattributed.append(err)
                continue
            if item.is_response and item.seq == seq:
                if item.type != type_:
                    raise ProtocolError(
                        f"{self.port}: answer to seq {seq} has type 0x{item.type:02X}, expected 0x{type_:02X}"
                    )
                return item
            # a stale answer (an earlier timed-out request) or a stray frame: dropped
        return None
