"""The medium's event loop: a unix stream socket, one connection per station.

Every frame a station sends is handled in arrival order (posted SPI writes included), then
:meth:`Medium.advance` moves virtual time as far as lock-step allows. Single-threaded, no
locks: the determinism of a run depends only on the order of each station's frames, which
the lock-step fixes.
"""

from __future__ import annotations

import os
import selectors
import signal
import socket
import sys
from dataclasses import dataclass, field
from typing import Final

from uwbcal.errors import UwbcalError
from uwbcal.link import proto_gen as pg
from uwbcal.medium import wire
from uwbcal.medium.core import Medium, Station
from uwbcal.medium.registers import SYS_TIME, TX_TIME

RECV_SIZE: Final = 1 << 16


@dataclass(eq=False)
class Conn:
    """One station connection.

    Frames sent to the station are collected in :attr:`out` and written with one system call
    when the server has handled everything that arrived (:meth:`flush`): the answers to a
    batch of pipelined reads go out together.
    """

    sock: socket.socket
    buf: bytearray = field(default_factory=bytearray)
    station: Station | None = None
    out: bytearray = field(default_factory=bytearray)
    dirty: list[Conn] | None = None     #: the server's list of connections with output

    def send(self, data: bytes) -> None:
        """Queue a frame for the station (written by :meth:`flush`)."""
        if not self.out and self.dirty is not None:
            self.dirty.append(self)
        self.out += data

    def flush(self) -> None:
        """Write the queued frames (blocking: the station is reading, it asked for them)."""
        data, self.out = self.out, bytearray()
        try:
            self.sock.sendall(data)
        except OSError:
            pass  # the station is gone; its EOF closes the connection


class MediumServer:
    """Accepts stations on ``path`` and runs the medium until stopped."""

    def __init__(self, medium: Medium, path: str, *, verbose: bool = False) -> None:
        self.medium = medium
        self.path = path
        self.verbose = verbose
        self.sel = selectors.DefaultSelector()
        if os.path.exists(path):
            os.unlink(path)
        self.listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.listener.bind(path)
        self.listener.listen(64)
        self.listener.setblocking(False)
        self.sel.register(self.listener, selectors.EVENT_READ, None)
        self.ctl_path = path + ".ctl"
        if os.path.exists(self.ctl_path):
            os.unlink(self.ctl_path)
        self.ctl = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.ctl.bind(self.ctl_path)
        self.ctl.listen(8)
        self.ctl.setblocking(False)
        self.sel.register(self.ctl, selectors.EVENT_READ, "ctl")
        self.running = True
        self.frames_in = 0
        self.dirty: list[Conn] = []

    def close(self) -> None:
        """Close every socket and remove the socket file."""
        for key in list(self.sel.get_map().values()):
            obj = key.fileobj
            if isinstance(obj, socket.socket):
                obj.close()
        self.ctl.close()
        self.sel.close()
        for p in (self.path, self.ctl_path):
            try:
                os.unlink(p)
            except OSError:
                pass

    def serve(self) -> None:
        """Run until :attr:`running` goes false (SIGTERM/SIGINT)."""
        timeout: float | None = None
        while self.running:
            for key, _ in self.sel.select(timeout):
                if key.data is None:
                    self._accept()
                elif key.data == "ctl":
                    self._control()
                else:
                    self._read(key.data)
            # Answers go out first; the World works while the stations that got them run
            # (Medium.settle: a delayed TX's emission, a frame's receptions).
            self._flush()
            self.medium.settle()
            timeout = self.medium.advance()
            self._flush()
            self.medium.settle()

    def _flush(self) -> None:
        if self.dirty:
            for conn in self.dirty:
                conn.flush()
            self.dirty.clear()

    def _accept(self) -> None:
        try:
            sock, _ = self.listener.accept()
        except BlockingIOError:
            return
        sock.setblocking(True)
        self.sel.register(sock, selectors.EVENT_READ, Conn(sock, dirty=self.dirty))

    def _control(self) -> None:
        """One command from the control socket (see uwbcal.medium.launcher)."""
        try:
            sock, _ = self.ctl.accept()
        except BlockingIOError:
            return
        with sock:
            sock.settimeout(5.0)
            data = b""
            try:
                while not data.endswith(b"\n") and len(data) < 4096:
                    chunk = sock.recv(4096)
                    if not chunk:
                        break
                    data += chunk
                answer = self.command(data.decode(errors="replace").split())
                sock.sendall(answer.encode() + b"\n")
            except OSError:
                pass

    def command(self, words: list[str]) -> str:
        """Execute a control command; the answer line starts with 'ok' or 'error'."""
        self.medium.settle()
        world = self.medium.world
        try:
            if words[:1] == ["move"] and len(words) == 5:
                move = getattr(world, "move", None)
                if move is None:
                    return "error this world cannot move stations"
                move(int(words[1]), (float(words[2]), float(words[3]), float(words[4])))
                return "ok"
            if words[:1] == ["where"] and len(words) == 2:
                pos = getattr(world, "position_m", None)
                if pos is None:
                    return "error this world has no positions"
                return "ok " + " ".join(repr(float(v)) for v in pos(int(words[1])))
            if words == ["stats"]:
                m = self.medium
                return (f"ok now_s={m.now_ps / 1e12:.6f} frames={m.frames} receptions={m.receptions} "
                        f"tunnel_frames={self.frames_in} paced_s={m.paced_ps / 1e12:.6f} "
                        f"idle_waits={m.idle_waits} physics_s={getattr(world, 'busy_s', 0.0):.3f} "
                        f"stations={sorted(m.stations)}")
        except (ValueError, UwbcalError) as exc:
            return f"error {exc}"
        return f"error unknown command {' '.join(words)!r} (move ID X Y Z | where ID | stats)"

    def _drop(self, conn: Conn) -> None:
        self.sel.unregister(conn.sock)
        conn.sock.close()
        if conn.station is not None:
            if self.verbose:
                print(f"medium: station {conn.station.sid} left at {self.medium.now_ps / 1e12:.6f} s",
                      file=sys.stderr)
            self.medium.bye(conn.station)

    def _read(self, conn: Conn) -> None:
        try:
            data = conn.sock.recv(RECV_SIZE)
        except OSError:
            data = b""
        if not data:
            self._drop(conn)
            return
        buf = conn.buf
        buf += data
        start = 0
        while True:
            end = buf.find(0, start)
            if end < 0:
                break
            if end > start:
                self._frame(conn, bytes(buf[start:end]))
            start = end + 1
        del buf[:start]

    def _frame(self, conn: Conn, chunk: bytes) -> None:
        self.frames_in += 1
        try:
            mtype, _flags, seq, payload = wire.decode(chunk)
        except wire.FrameError as exc:
            conn.send(wire.error_frame(0, exc.code, 0))
            return
        # Deferred World work is done before anything that could see it or call the World;
        # only an SPI read of another register than SYS_TIME (the World's clock) and TX_TIME
        # (set by a deferred TX) may be answered first.
        if self.medium.deferred and not (mtype == wire.TUN_SPI_READ and len(payload) >= 3
                                         and (payload[2] & 0x3F) not in (SYS_TIME, TX_TIME)):
            self.medium.settle()
        st = conn.station
        if mtype == wire.TUN_SPI_WRITE:
            if st is not None and len(payload) >= 2:
                n = payload[0]
                st.model.spi_write(payload[1:1 + n], payload[1 + n:])
            return
        if mtype == wire.TUN_SPI_READ:
            if st is None or len(payload) < 3:
                conn.send(wire.error_frame(seq, pg.ERR_BAD_LENGTH, mtype, len(payload)))
                return
            n = payload[0] | (payload[1] << 8)
            conn.send(wire.response(mtype, seq, st.model.spi_read(payload[2:], n)))
            return
        if mtype == wire.TUN_WAIT:
            if st is None or len(payload) != wire.WAIT_REQ.size:
                conn.send(wire.error_frame(seq, pg.ERR_BAD_LENGTH, mtype, len(payload)))
                return
            deadline_us, mode = wire.WAIT_REQ.unpack(payload)
            self.medium.start_wait(st, seq, deadline_us, mode)
            return
        if mtype == wire.TUN_CANCEL:
            if st is not None:
                self.medium.cancel(st)
            return
        if mtype == wire.TUN_HELLO:
            if len(payload) != wire.HELLO_REQ.size:
                conn.send(wire.error_frame(seq, pg.ERR_BAD_LENGTH, mtype, len(payload)))
                return
            sid, _uid = wire.HELLO_REQ.unpack(payload)
            if sid not in self.medium.world.station_ids():
                print(f"medium: refused station {sid}: not in the scenario "
                      f"{self.medium.world.station_ids()}", file=sys.stderr)
                conn.send(wire.error_frame(seq, pg.ERR_BAD_VALUE, mtype, 0))
                return
            if conn.station is not None:
                self.medium.bye(conn.station)
            conn.station = self.medium.hello(sid, conn.send)
            if self.verbose:
                print(f"medium: station {sid} joined at {self.medium.now_ps / 1e12:.6f} s", file=sys.stderr)
            conn.send(wire.response(mtype, seq, wire.U64.pack(self.medium.now_ps // 10**6)))
            return
        if mtype == wire.TUN_RESET:
            if st is not None:
                st.radio_off()
                st.model.reset()
            conn.send(wire.response(mtype, seq, b""))
            return
        conn.send(wire.error_frame(seq, pg.ERR_UNKNOWN_TYPE, mtype, mtype))


def install_signal_handlers(server: MediumServer) -> None:
    """SIGTERM and SIGINT stop the loop cleanly."""

    def stop(_sig: int, _frame: object) -> None:
        server.running = False
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
