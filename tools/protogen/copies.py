"""Find hand-written copies of facts that protocol/ defines once (`make gen-check` fails on any).

Facts of the definition (message types, error codes, flags, enum values, constants, chip facts,
struct layouts) must reach hand-written code only through the generated files. This scan reads
the hand-written sources (host/uwbcal, firmware, tools/bench; not the generated files, not the
generator, not the tests, which state expected values on purpose) and reports:

- a named copy: an identifier that ends with a fact's name given that fact's literal value
  (``ERR_BAD_CRC: Final = 2``, ``#define TABLE_SLOT_TORN 2``, ``MODE_IDLE = 0x01``,
  ``TUN_WAIT = 0x43``);
- a distinctive value: a numeric literal equal to a scalar constant whose value is unlikely by
  chance (a non-round float such as 1.14 or 5000.0, an integer >= 0x1000 other than a power of
  two);
- a value list: the values of a list constant written out in order (``64, 128, 256, 512, ...``);
- a layout: a ``struct.Struct("<...")`` format equal to a tunnel message's generated layout.

What it cannot see: a copy written as an expression (``128 * 499.2e6``), a fact renamed beyond
recognition with a common value (``x = 32``), and facts in prose. A line may carry the marker
``not-a-copy:`` with a reason when a value only coincides with a fact.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path

from protogen.model import ChipFacts, Protocol
from protogen.py_code import struct_format

#: Hand-written source trees scanned, relative to the repository root.
SCAN = ("host/uwbcal", "firmware", "tools/bench")
#: Generated files (never scanned).
GENERATED = {
    "firmware/core/proto_gen.h", "firmware/core/proto_gen.c", "host/uwbcal/link/proto_gen.py",
    "firmware/dw1000/dw1000_facts.h", "host/uwbcal/dw1000_facts.py",
}
MARKER = "not-a-copy:"
_NUM = re.compile(r"(?<![\w.])(0[xX][0-9a-fA-F_]+|\d[\d_]*(?:\.\d*)?(?:[eE][+-]?\d+)?)[uUlLfF]*(?![\w.])")
_STRUCT_FMT = re.compile(r"""struct\.Struct\(\s*["'](<[^"']+)["']""")


def _value(lit: str) -> int | float | None:
    try:
        if lit.lower().startswith("0x"):
            return int(lit.replace("_", ""), 16)
        if re.fullmatch(r"[\d_]+", lit):
            return int(lit.replace("_", ""))
        return float(lit.replace("_", ""))
    except ValueError:
        return None


def _distinctive(v: int | float) -> bool:
    if isinstance(v, float) and not v.is_integer():
        return True
    x = abs(v)
    if isinstance(v, float):
        return x >= 1000 and x not in (1000.0, 1e6, 1e9, 1e12)
    return x >= 0x1000 and x & (x - 1) != 0


_ANY = r"(?:\w*_)?"


def _named(p: Protocol, chip: ChipFacts) -> list[tuple[str, int | float]]:
    """(identifier regex, value) of every named integer fact: the names a copy would carry."""
    out = [(rf"(?:T_|MSG_|TYPE_)?{m.name.upper()}", m.type) for m in p.messages]
    out += [(rf"(?:\w*ERR\w*_){k.upper()}", c) for k, (c, _) in p.errors.items()]
    out += [(rf"(?:\w*FLAGS?_){k.upper()}", v) for k, v in p.flags.items()]
    for e in list(p.enums.values()) + list(chip.enums.values()):
        # the full name and the short forms a hand-written copy would use: SLOT_TORN, MODE_IDLE
        words = "|".join([e.name.upper(), *e.name.upper().split("_")])
        out += [(rf"{_ANY}(?:{words})_{v.name.upper()}", v.value) for v in e.values]
    for c in list(p.constants.values()) + list(chip.constants.values()):
        if not isinstance(c.value, tuple):
            out.append((_ANY + c.name.upper().removeprefix("TABLE_"), c.value))
    return out


def _enum_maps(p: Protocol) -> list[tuple[str, re.Pattern[str]]]:
    """A hand-written value -> name map of an enum: ``{0: "empty", 1: "valid"``."""
    out = []
    for e in p.enums.values():
        if len(e.values) < 2:
            continue
        pair = [rf"""{v.value}\s*:\s*["']{v.name}["']""" for v in e.values[:2]]
        out.append((e.name, re.compile(rf"\b{pair[0]}\s*,\s*{pair[1]}")))
    return out


def _lists(p: Protocol, chip: ChipFacts) -> list[tuple[str, re.Pattern[str]]]:
    out = []
    for c in list(p.constants.values()) + list(chip.constants.values()):
        if isinstance(c.value, tuple) and len(c.value) >= 3:
            sep = r"[uU]?\s*,\s*"
            out.append((c.name, re.compile(r"(?<![\w.])" + sep.join(re.escape(str(v)) for v in c.value))))
    return out


def _layouts(p: Protocol) -> dict[str, str]:
    """'<fmt' -> message name, for the tunnel messages' fixed parts (the hot path's layouts)."""
    out: dict[str, str] = {}
    for m in p.messages:
        if m.range_name != "tunnel":
            continue
        for fields in (m.request, m.response):
            fixed = [f for f in fields if f.t.kind not in ("tail", "tail_struct")]
            fmt = "<" + struct_format(fixed, p)
            if len(fmt) > 2:
                out.setdefault(fmt, m.name)
    for s in p.structs.values():
        if s.source == "tunnel.toml":
            out.setdefault("<" + struct_format(s.fields, p), s.name)
    return out


def files(root: Path) -> Iterable[Path]:
    """The hand-written source files the scan reads."""
    for top in SCAN:
        for path in sorted((root / top).rglob("*")):
            rel = path.relative_to(root).as_posix()
            if path.suffix in (".py", ".c", ".h") and rel not in GENERATED and "/build/" not in rel:
                yield path


def find_copies(root: Path, p: Protocol, chip: ChipFacts,
                paths: Iterable[Path] | None = None) -> list[str]:
    """One line per hand-written copy found: ``path:line: what``."""
    values: dict[tuple[type, int | float], str] = {}  # (int or float, value): an int is no float
    for c in list(p.constants.values()) + list(chip.constants.values()):
        # a list constant's elements are values in their own right (6810 kb/s as a parameter
        # default is no copy of the list): lists are checked as lists
        if not isinstance(c.value, tuple) and _distinctive(c.value):
            values.setdefault((type(c.value), c.value), c.name)
    named = _named(p, chip)
    # NAME [: type] = literal, or #define NAME literal (the literal parsed and compared)
    named_re = [
        (v, re.compile(
            rf"\b{n}\b\s*(?::[^=\n]*)?(?:=|\s)\s*\(?\s*(-?)({_NUM.pattern})\s*\)?\s*(?:$|[,;)}}/#])",
            re.IGNORECASE))
        for n, v in named
    ]
    maps = _enum_maps(p)
    lists = _lists(p, chip)
    layouts = _layouts(p)
    bad: list[str] = []
    for path in paths if paths is not None else files(root):
        rel = path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)
        for i, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if MARKER in line:
                continue
            code = line.split("//", 1)[0] if path.suffix != ".py" else line.split("#", 1)[0]
            code = re.sub(r"/\*.*?\*/", "", code)
            if not code.strip() or code.lstrip().startswith(("*", '"""', "/*")):
                continue
            for m in _NUM.finditer(code):
                v = _value(m.group(1))
                if v is not None and (type(v), v) in values:
                    bad.append(f"{rel}:{i}: {m.group(0)} is the value of {values[(type(v), v)]}")
            for v, rx in named_re:
                nm = rx.search(code)
                if nm is not None:
                    lit = _value(nm.group(3))
                    if lit is not None and type(lit) is type(v) and (-lit if nm.group(1) else lit) == v:
                        bad.append(f"{rel}:{i}: {nm.group(0).strip()} written by hand")
            for name, rx in maps:
                if rx.search(code):
                    bad.append(f"{rel}:{i}: the names of {name} written out")
            for name, rx in lists:
                if rx.search(code):
                    bad.append(f"{rel}:{i}: the values of {name} written out")
            for fm in _STRUCT_FMT.finditer(code):
                if fm.group(1) in layouts:
                    bad.append(f"{rel}:{i}: layout {fm.group(1)} of {layouts[fm.group(1)]} written by hand")
    return bad


__all__ = ["MARKER", "files", "find_copies"]
