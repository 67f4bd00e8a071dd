"""A Python client of the medium tunnel: what firmware/boards/native/radio_tunnel.c does, in Python.

Used by the tests (to drive the medium without firmware) and by tools/bench to measure the
medium's own cost per SPI transaction. Blocking, one socket, one station.
"""

from __future__ import annotations

import socket

from uwbcal.medium import wire


class TunnelClient:
    """One station's end of the tunnel."""

    def __init__(self, path: str, station_id: int, uid: bytes = b"\0" * 12) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(path)
        self.seq = 0
        self.buf = bytearray()
        self.now_us = wire.U64.unpack(self._request(wire.TUN_HELLO,
                                                    wire.HELLO_REQ.pack(station_id, uid)))[0]

    def close(self) -> None:
        """Disconnect."""
        self.sock.close()

    def _send(self, mtype: int, payload: bytes) -> int:
        self.seq = (self.seq + 1) & 0xFFFF
        self.sock.sendall(wire.encode(mtype, self.seq, payload))
        return self.seq

    def _recv_frame(self) -> tuple[int, int, int, bytes]:
        while True:
            end = self.buf.find(0)
            if end >= 0:
                chunk = bytes(self.buf[:end])
                del self.buf[:end + 1]
                if chunk:
                    return wire.decode(chunk)
                continue
            data = self.sock.recv(1 << 16)
            if not data:
                raise ConnectionError("medium closed the tunnel")
            self.buf += data

    def _request(self, mtype: int, payload: bytes) -> bytes:
        seq = self._send(mtype, payload)
        rtype, _flags, rseq, body = self._recv_frame()
        if rtype == wire.ERROR:
            raise RuntimeError(f"medium answered ERROR {wire.ERROR_RESP.unpack(body)}")
        if rtype != mtype or rseq != seq:
            raise RuntimeError(f"unexpected answer type {rtype:#x} seq {rseq} to {mtype:#x} seq {seq}")
        return body

    @staticmethod
    def header(write: bool, rid: int, off: int = 0) -> bytes:
        """The shortest DW1000 SPI header for (rid, off) (REGISTERS.md section 1)."""
        b0 = (0x80 if write else 0) | rid
        if off == 0:
            return bytes([b0])
        if off < 0x80:
            return bytes([b0 | 0x40, off])
        return bytes([b0 | 0x40, 0x80 | (off & 0x7F), off >> 7])

    def write(self, rid: int, off: int, data: bytes) -> None:
        """Posted SPI write."""
        hdr = self.header(True, rid, off)
        self._send(wire.TUN_SPI_WRITE, bytes([len(hdr)]) + hdr + data)

    def write_int(self, rid: int, off: int, value: int, n: int) -> None:
        """Posted SPI write of an n-byte little-endian integer."""
        self.write(rid, off, value.to_bytes(n, "little"))

    def read(self, rid: int, off: int, n: int) -> bytes:
        """SPI read of n bytes."""
        hdr = self.header(False, rid, off)
        return self._request(wire.TUN_SPI_READ, n.to_bytes(2, "little") + hdr)

    def read_int(self, rid: int, off: int, n: int) -> int:
        """SPI read of an n-byte little-endian integer."""
        return int.from_bytes(self.read(rid, off, n), "little")

    def wait(self, deadline_us: int, mode: int = 0) -> tuple[int, bool]:
        """tun_wait: (now_us, irq) on waking."""
        now, irq = wire.WAIT_RESP.unpack(self._request(wire.TUN_WAIT, wire.WAIT_REQ.pack(deadline_us, mode)))
        self.now_us = now
        return now, bool(irq)

    def wait_snapshot(self, deadline_us: int, mode: int = wire.MODE_SNAPSHOT
                      ) -> tuple[int, bool, list[tuple[int, int, bytes]]]:
        """tun_wait with a snapshot (mode bit2 added): (now_us, irq, blocks (rid, off, bytes))."""
        body = self._request(wire.TUN_WAIT, wire.WAIT_REQ.pack(deadline_us, mode | wire.MODE_SNAPSHOT))
        now, irq = wire.WAIT_RESP.unpack_from(body)
        self.now_us = now
        return now, bool(irq), wire.parse_snapshot(body[wire.WAIT_RESP.size:])

    def send_wait(self, deadline_us: int, mode: int = 0) -> None:
        """Send tun_wait without reading the answer (use :meth:`cancel` / :meth:`wait_answer`)."""
        self._pending = self._send(wire.TUN_WAIT, wire.WAIT_REQ.pack(deadline_us, mode))

    def cancel(self) -> None:
        """Posted tun_cancel."""
        self._send(wire.TUN_CANCEL, b"")

    def wait_answer(self) -> tuple[int, bool]:
        """The answer to the last :meth:`send_wait`."""
        rtype, _f, rseq, body = self._recv_frame()
        if rtype != wire.TUN_WAIT or rseq != self._pending:
            raise RuntimeError(f"unexpected answer type {rtype:#x} seq {rseq}")
        now, irq = wire.WAIT_RESP.unpack(body)
        self.now_us = now
        return now, bool(irq)

    def reset(self) -> None:
        """tun_reset."""
        self._request(wire.TUN_RESET, b"")
