"""A GDB remote serial protocol stub for the emulated EVK1000 (enough for ``load``).

What a debugger does to a board through OpenOCD's GDB server, done to the emulated one: the
stub listens on TCP, the machine stays halted while a debugger is attached, and it offers

- registers: ``g``/``G``, ``p``/``P`` with an M-profile target description (r0-r12, sp,
  lr, pc, xpsr);
- memory: ``m``, ``M``, ``X`` (RAM and flash reads, RAM writes);
- flash: a memory map (``qXfer:memory-map:read``: flash 256 KB in 2 KB blocks, RAM 64 KB),
  so GDB's ``load`` erases and programs with ``vFlashErase``/``vFlashWrite``/``vFlashDone``
  as it does through OpenOCD; the data goes to the station's flash file;
- ``monitor reset`` (``qRcmd``), ``c`` (continue: detach and run), ``D`` (detach), ``k``.

Breakpoints and single-stepping are not offered (``Z``/``s`` answer empty: unsupported).
"""

from __future__ import annotations

import socket
import struct
from typing import Final

from unicorn import arm_const as A

from uwbcal.evk1000.fpec import FLASH_BASE, FLASH_SIZE, PAGE_SIZE
from uwbcal.evk1000.machine import SRAM_BASE, SRAM_SIZE, Machine

REGS: Final = (A.UC_ARM_REG_R0, A.UC_ARM_REG_R1, A.UC_ARM_REG_R2, A.UC_ARM_REG_R3, A.UC_ARM_REG_R4,
               A.UC_ARM_REG_R5, A.UC_ARM_REG_R6, A.UC_ARM_REG_R7, A.UC_ARM_REG_R8, A.UC_ARM_REG_R9,
               A.UC_ARM_REG_R10, A.UC_ARM_REG_R11, A.UC_ARM_REG_R12, A.UC_ARM_REG_SP, A.UC_ARM_REG_LR,
               A.UC_ARM_REG_PC, A.UC_ARM_REG_XPSR)
TARGET_XML: Final = (
    '<?xml version="1.0"?><!DOCTYPE target SYSTEM "gdb-target.dtd"><target><architecture>arm'
    '</architecture><feature name="org.gnu.gdb.arm.m-profile">'
    + "".join(f'<reg name="r{i}" bitsize="32" regnum="{i}"/>' for i in range(13))
    + '<reg name="sp" bitsize="32" type="data_ptr" regnum="13"/><reg name="lr" bitsize="32" regnum="14"/>'
    '<reg name="pc" bitsize="32" type="code_ptr" regnum="15"/><reg name="xpsr" bitsize="32" regnum="16"/>'
    "</feature></target>")
MEMORY_MAP: Final = (
    '<?xml version="1.0"?><!DOCTYPE memory-map PUBLIC "+//IDN gnu.org//DTD GDB Memory Map V1.0//EN" '
    '"http://sourceware.org/gdb/gdb-memory-map.dtd"><memory-map>'
    f'<memory type="flash" start="{FLASH_BASE:#x}" length="{FLASH_SIZE:#x}">'
    f'<property name="blocksize">{PAGE_SIZE:#x}</property></memory>'
    f'<memory type="ram" start="{SRAM_BASE:#x}" length="{SRAM_SIZE:#x}"/></memory-map>')


def checksum(data: bytes) -> bytes:
    """The two hex digits after '#'."""
    return b"%02x" % (sum(data) & 0xFF)


def unescape(data: bytes) -> bytes:
    """Binary data of X / vFlashWrite: '}' escapes the next byte (xor 0x20)."""
    out = bytearray()
    it = iter(data)
    for b in it:
        out.append(next(it) ^ 0x20 if b == 0x7D else b)
    return bytes(out)


class GdbStub:
    """One debugger session at a time on a TCP port, the machine halted meanwhile."""

    def __init__(self, machine: Machine, host: str = "127.0.0.1", port: int = 0) -> None:
        self.m = machine
        self.listener = socket.create_server((host, port))
        self.port = self.listener.getsockname()[1]
        self.flash_writes = 0

    def close(self) -> None:
        """Stop listening."""
        self.listener.close()

    def serve_session(self) -> str:
        """Accept one debugger and answer it until it detaches, kills or continues; returns
        how it ended ("detach", "kill", "continue" or "closed")."""
        conn, _ = self.listener.accept()
        with conn:
            buf = b""
            while True:
                data = conn.recv(65536)
                if not data:
                    return "closed"
                buf += data
                while True:
                    buf = buf.lstrip(b"+-\x03")
                    start = buf.find(b"$")
                    end = buf.find(b"#", start)
                    if start < 0 or end < 0 or len(buf) < end + 3:
                        break
                    body = buf[start + 1:end]
                    ok = buf[end + 1:end + 3].lower() == checksum(body)
                    buf = buf[end + 3:]
                    conn.sendall(b"+" if ok else b"-")
                    if not ok:
                        continue
                    reply, end_how = self.handle(unescape_rsp(body))
                    conn.sendall(b"$" + reply + b"#" + checksum(reply))
                    if end_how:
                        return end_how

    # ---- packets -----------------------------------------------------------------------
    def handle(self, pkt: bytes) -> tuple[bytes, str | None]:
        """The reply to one packet, and how the session ends after it (None: it goes on)."""
        uc = self.m.uc
        try:
            if pkt == b"?":
                return b"S05", None
            if pkt.startswith(b"qSupported"):
                return b"PacketSize=4000;qXfer:features:read+;qXfer:memory-map:read+", None
            if pkt.startswith(b"qXfer:features:read:target.xml:"):
                return _xfer(TARGET_XML, pkt), None
            if pkt.startswith(b"qXfer:memory-map:read::"):
                return _xfer(MEMORY_MAP, pkt), None
            if pkt == b"qAttached":
                return b"1", None
            if pkt in (b"qC",):
                return b"QC1", None
            if pkt == b"qfThreadInfo":
                return b"m1", None
            if pkt == b"qsThreadInfo":
                return b"l", None
            if pkt.startswith(b"H") or pkt == b"!":
                return b"OK", None
            if pkt == b"g":
                self.m.uc.reg_write(A.UC_ARM_REG_PC, self.m.pc)
                return b"".join(struct.pack("<I", uc.reg_read(r)).hex().encode() for r in REGS), None
            if pkt.startswith(b"p"):
                n = int(pkt[1:], 16)
                if n >= len(REGS):
                    return b"E01", None
                v = self.m.pc if REGS[n] == A.UC_ARM_REG_PC else uc.reg_read(REGS[n])
                return struct.pack("<I", v).hex().encode(), None
            if pkt.startswith(b"P"):
                n_s, v_s = pkt[1:].split(b"=")
                n, v = int(n_s, 16), struct.unpack("<I", bytes.fromhex(v_s.decode()))[0]
                if n >= len(REGS):
                    return b"E01", None
                uc.reg_write(REGS[n], v)
                if REGS[n] == A.UC_ARM_REG_PC:
                    self.m.pc = v & ~1
                return b"OK", None
            if pkt.startswith(b"m"):
                addr, n = (int(x, 16) for x in pkt[1:].split(b","))
                if not _in_memory(addr, n):
                    return b"E01", None
                return bytes(uc.mem_read(addr, n)).hex().encode(), None
            if pkt.startswith(b"M") or pkt.startswith(b"X"):
                head, data = pkt[1:].split(b":", 1)
                addr, n = (int(x, 16) for x in head.split(b","))
                raw = bytes.fromhex(data.decode()) if pkt[:1] == b"M" else data
                if not (SRAM_BASE <= addr and addr + n <= SRAM_BASE + SRAM_SIZE):
                    return b"E01", None          # flash only through vFlash (as OpenOCD)
                uc.mem_write(addr, raw[:n])
                return b"OK", None
            if pkt.startswith(b"vFlashErase:"):
                addr, n = (int(x, 16) for x in pkt[12:].split(b","))
                off = addr - FLASH_BASE
                if off % PAGE_SIZE or n % PAGE_SIZE or not 0 <= off <= FLASH_SIZE - n:
                    return b"E01", None
                self._store(off, b"\xff" * n)
                return b"OK", None
            if pkt.startswith(b"vFlashWrite:"):
                head, data = pkt[12:].split(b":", 1)
                off = int(head, 16) - FLASH_BASE
                if not 0 <= off <= FLASH_SIZE - len(data):
                    return b"E01", None
                old = self.m.flash.data[off:off + len(data)]
                self._store(off, bytes(a & b for a, b in zip(old, data, strict=True)))   # 1 -> 0 only
                self.flash_writes += 1
                return b"OK", None
            if pkt == b"vFlashDone":
                return b"OK", None
            if pkt.startswith(b"qRcmd,"):
                cmd = bytes.fromhex(pkt[6:].decode()).decode(errors="replace").strip()
                if cmd in ("reset", "reset halt", "reset init"):
                    self.m.reset()
                    return b"OK", None
                return b"E01", None               # only `monitor reset` is known
            if pkt.startswith(b"c"):
                return b"OK", "continue"
            if pkt.startswith(b"D"):
                return b"OK", "detach"
            if pkt == b"k":
                return b"OK", "kill"
        except (ValueError, IndexError):
            return b"E02", None
        return b"", None                          # unsupported: GDB falls back or says so

    def _store(self, off: int, data: bytes) -> None:
        self.m.flash.store(off, data)
        self.m.uc.mem_write(FLASH_BASE + off, data)


def unescape_rsp(body: bytes) -> bytes:
    """Undo the RSP escape ('}' x^0x20) of a packet body (binary packets carry it)."""
    return unescape(body) if b"}" in body else body


def _in_memory(addr: int, n: int) -> bool:
    return (FLASH_BASE <= addr and addr + n <= FLASH_BASE + FLASH_SIZE) or \
        (SRAM_BASE <= addr and addr + n <= SRAM_BASE + SRAM_SIZE)


def _xfer(doc: str, pkt: bytes) -> bytes:
    """qXfer read reply for ``...:offset,length``."""
    off_s, len_s = pkt.rsplit(b":", 1)[1].split(b",")
    off, n = int(off_s, 16), int(len_s, 16)
    chunk = doc.encode()[off:off + n]
    return (b"m" if off + n < len(doc) else b"l") + chunk
