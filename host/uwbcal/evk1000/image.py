"""The image an emulated EVK1000 runs, and the symbols of its ELF file when there is one.

The machine executes the flash contents only (the .bin as ``uwbcal flash`` writes it); the
ELF beside the .bin, if present and matching, gives names for error messages ("PC
0x08001234 in flash_wait+0x12"), the end of static RAM (for the stack high-water mark) and
the address range of ``board_idle`` (so a WFI there tells the medium the station idles).
Reading symbols never changes what the image does.
"""

from __future__ import annotations

import bisect
import struct
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Symbols:
    """Function and object symbols of an ELF32 little-endian file."""

    by_name: dict[str, tuple[int, int]] = field(default_factory=dict)   #: name -> (value, size)
    _starts: list[int] = field(default_factory=list)
    _names: list[str] = field(default_factory=list)

    @classmethod
    def from_elf(cls, path: str | Path) -> Symbols:
        """Read .symtab/.strtab; an unreadable or foreign file gives no symbols."""
        syms = cls()
        try:
            data = Path(path).read_bytes()
        except OSError:
            return syms
        if data[:4] != b"\x7fELF" or data[4] != 1 or data[5] != 1:
            return syms
        shoff, = struct.unpack_from("<I", data, 0x20)
        shentsize, shnum = struct.unpack_from("<HH", data, 0x2E)
        sections = [struct.unpack_from("<IIIIIIIIII", data, shoff + i * shentsize) for i in range(shnum)]
        for sh in sections:
            if sh[1] != 2:                                   # SHT_SYMTAB
                continue
            strtab = sections[sh[6]]
            for off in range(sh[4], sh[4] + sh[5], 16):
                name_off, value, size, info = struct.unpack_from("<IIIB", data, off)
                if name_off == 0 or (info & 0xF) not in (0, 1, 2):  # NOTYPE, OBJECT, FUNC
                    continue
                s = strtab[4] + name_off
                name = data[s:data.index(b"\0", s)].decode(errors="replace")
                if name and not name.startswith("$"):
                    syms.by_name[name] = (value & ~1 if (info & 0xF) == 2 else value, size)
        funcs = sorted((v, n) for n, (v, _s) in syms.by_name.items() if 0x08000000 <= v < 0x08040000)
        syms._starts = [v for v, _ in funcs]
        syms._names = [n for _, n in funcs]
        return syms

    def addr(self, name: str) -> int | None:
        """The value of symbol ``name``."""
        v = self.by_name.get(name)
        return v[0] if v else None

    def range(self, name: str) -> tuple[int, int] | None:
        """[start, end) of function ``name``."""
        v = self.by_name.get(name)
        return (v[0], v[0] + v[1]) if v else None

    def describe(self, addr: int) -> str:
        """``0x08001234 (name+0x12)`` or just the address."""
        i = bisect.bisect_right(self._starts, addr) - 1
        if i < 0:
            return f"{addr:#010x}"
        return f"{addr:#010x} ({self._names[i]}+{addr - self._starts[i]:#x})"


def elf_beside(image: Path) -> Path | None:
    """The .elf next to a .bin, if there is one."""
    elf = image.with_suffix(".elf")
    return elf if elf.is_file() else None
