"""Python output: host/uwbcal/link/proto_gen.py (constants, dataclasses); the runtime it imports is the hand-written uwbcal.link.wire_runtime."""

# ruff: noqa: E501  (templates of generated lines, kept whole to stay readable)
from __future__ import annotations

from protogen.layout import dispatched, msg_parts, struct_order, tail_max
from protogen.model import (
    BANNER,
    NP_SCALARS,
    SCALARS,
    Constant,
    Enum,
    Field,
    Protocol,
)


def camel(name: str) -> str:
    return "".join(w.capitalize() for w in name.split("_"))


def _slots(f: Field, p: Protocol) -> int:
    t = f.t
    if t.kind in ("scalar", "bytes", "str"):
        return 1
    if t.kind == "array":
        return t.n
    if t.kind == "struct":
        return _struct_slots(t.base, p)
    if t.kind == "struct_array":
        return t.n * _struct_slots(t.base, p)
    return 0


def _struct_slots(name: str, p: Protocol) -> int:
    return sum(_slots(f, p) for f in p.structs[name].fields)


def struct_format(fields: list[Field], p: Protocol) -> str:
    parts = []
    for f in fields:
        t = f.t
        if t.kind == "scalar":
            parts.append(SCALARS[t.base][1])
        elif t.kind == "array":
            parts.append(f"{t.n}{SCALARS[t.base][1]}")
        elif t.kind in ("bytes", "str"):
            parts.append(f"{t.n}s")
        elif t.kind == "struct":
            parts.append(struct_format(p.structs[t.base].fields, p))
        elif t.kind == "struct_array":
            parts.append(struct_format(p.structs[t.base].fields, p) * t.n)
    return "".join(parts)


def _py_annot(f: Field) -> tuple[str, str]:
    t = f.t
    if t.kind == "scalar":
        return ("float", "0.0") if t.base.startswith("f") else ("int", "0")
    if t.kind == "array":
        z = "0.0" if t.base.startswith("f") else "0"
        ty = "float" if t.base.startswith("f") else "int"
        return f"tuple[{ty}, ...]", "(" + ", ".join([z] * t.n) + ("," if t.n == 1 else "") + ")"
    if t.kind == "bytes":
        return "_Bytes", f"_Bytes({t.n})"
    if t.kind == "str":
        return "str", '""'
    if t.kind == "struct":
        return camel(t.base), f"field(default_factory={camel(t.base)})"
    if t.kind == "struct_array":
        return (
            f"tuple[{camel(t.base)}, ...]",
            f"field(default_factory=lambda: tuple({camel(t.base)}() for _ in range({t.n})))",
        )
    if t.kind == "tail":
        return "_Bytes", 'b""'
    return f"tuple[{camel(t.base)}, ...]", "()"


def _py_values(fields: list[Field]) -> list[str]:
    out = []
    for f in fields:
        t, x = f.t, f"self.{f.name}"
        if t.kind == "scalar":
            out.append(x)
        elif t.kind == "array":
            out.append(f"*_arr({x}, {t.n}, {f.name!r})")
        elif t.kind == "bytes":
            out.append(f"_fixed({x}, {t.n}, {f.name!r})")
        elif t.kind == "str":
            out.append(f"_str({x}, {t.n}, {f.name!r})")
        elif t.kind == "struct":
            out.append(f"*{x}._values()")
        elif t.kind == "struct_array":
            out.append(f"*(v for s in _arr({x}, {t.n}, {f.name!r}) for v in s._values())")
    return out


def _py_from_values(fields: list[Field], p: Protocol) -> list[str]:
    out = []
    i = 0
    for f in fields:
        t = f.t
        k = _slots(f, p)
        if t.kind == "scalar":
            out.append(f"{f.name}=v[{i}]")
        elif t.kind == "array":
            out.append(f"{f.name}=tuple(v[{i}:{i + k}])")
        elif t.kind == "bytes":
            out.append(f"{f.name}=bytes(v[{i}])")
        elif t.kind == "str":
            out.append(f"{f.name}=_unstr(v[{i}])")
        elif t.kind == "struct":
            out.append(f"{f.name}={camel(t.base)}._from_values(v[{i}:{i + k}])")
        elif t.kind == "struct_array":
            sk = _struct_slots(t.base, p)
            out.append(
                f"{f.name}=tuple({camel(t.base)}._from_values(v[j:j + {sk}]) for j in range({i}, {i + k}, {sk}))"
            )
        i += k
    return out


def _py_np_fields(fields: list[Field]) -> str:
    items = []
    for f in fields:
        t = f.t
        if t.kind == "scalar":
            items.append(f"({f.name!r}, {NP_SCALARS[t.base]!r})")
        elif t.kind == "array":
            items.append(f"({f.name!r}, {NP_SCALARS[t.base]!r}, ({t.n},))")
        elif t.kind == "bytes":
            items.append(f"({f.name!r}, 'V{t.n}')")
        elif t.kind == "str":
            items.append(f"({f.name!r}, 'S{t.n}')")
        elif t.kind == "struct":
            items.append(f"({f.name!r}, numpy_dtype({camel(t.base)}))")
        elif t.kind == "struct_array":
            items.append(f"({f.name!r}, numpy_dtype({camel(t.base)}), ({t.n},))")
    return "[" + ", ".join(items) + "]"


PY_HEAD = '''\
"""{banner}

The uwbcal wire protocol: constants, one frozen dataclass per struct and per message
direction, each with ``encode() -> bytes`` and ``decode(bytes)``. Little-endian, no padding.
The base classes and packing helpers are the hand-written uwbcal.link.wire_runtime.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any, ClassVar, Final, Self, TypeAlias

from uwbcal.link.wire_runtime import Message as Message
from uwbcal.link.wire_runtime import Request as Request
from uwbcal.link.wire_runtime import WireStruct as WireStruct
from uwbcal.link.wire_runtime import arr as _arr
from uwbcal.link.wire_runtime import fixed as _fixed
from uwbcal.link.wire_runtime import numpy_dtype as numpy_dtype
from uwbcal.link.wire_runtime import pack as _pack
from uwbcal.link.wire_runtime import records_array as records_array
from uwbcal.link.wire_runtime import str_bytes as _str
from uwbcal.link.wire_runtime import unstr as _unstr

PROTOCOL_VERSION: Final = {version}
MAX_PAYLOAD: Final = {max_payload}  # bytes, payload only
HEADER_SIZE: Final = {header_size}  # version u8, type u8, flags u8, seq u16
CRC_SIZE: Final = 4
CRC_NAME: Final = {crc_name!r}
CRC_CRCMOD: Final = {crc_crcmod!r}  # crcmod.predefined name
CRC_CHECK: Final = 0x{crc_check:08X}  # CRC of b"123456789"
DELIMITER: Final = 0x{delimiter:02X}
FRAME_MAX: Final = HEADER_SIZE + MAX_PAYLOAD + CRC_SIZE  # decoded frame, bytes
DETAIL_NONE: Final = 0xFFFF
HEADER: Final = struct.Struct("<BBBH")
_Bytes: TypeAlias = bytes  # a field may be named `bytes`
'''

def py_constants(consts: dict[str, Constant]) -> list[str]:
    """``NAME: Final = value  # doc [unit]`` per [[constant]] (a list value becomes a tuple)."""
    L = ["\n# constants"] if consts else []
    for c in consts.values():
        note = f"  # {c.doc}" + (f" [{c.unit}]" if c.unit else "")
        if isinstance(c.value, tuple):
            items = ", ".join(repr(v) for v in c.value) + ("," if len(c.value) == 1 else "")
            L.append(f"{c.name.upper()}: Final = ({items}){note}")
        elif c.type.startswith("u") and int(c.value) > 0xFFFF:
            L.append(f"{c.name.upper()}: Final = 0x{int(c.value):08X}{note}")
        else:
            L.append(f"{c.name.upper()}: Final = {c.value!r}{note}")
    return L


def py_enums(enums: dict[str, Enum]) -> list[str]:
    """``ENUM_VALUE: Final`` per value and ``ENUM_NAMES`` (value -> name) per [[enum]]."""
    L: list[str] = []
    for e in enums.values():
        L.append(f"\n# {e.name}: {e.doc}")
        for v in e.values:
            val = f"0x{v.value:02X}" if e.bits else str(v.value)
            L.append(f"{e.name.upper()}_{v.name.upper()}: Final = {val}  # {v.doc}")
        L.append(f"{e.name.upper()}_NAMES: Final[dict[int, str]] = {{")
        L += [f"    {v.value}: {v.name!r}," for v in e.values]
        L.append("}")
    return L


def gen_python(p: Protocol) -> str:
    L = [
        PY_HEAD.format(
            banner=BANNER,
            version=p.version,
            max_payload=p.max_payload,
            header_size=p.header_size,
            crc_name=p.crc_name,
            crc_crcmod=p.crc_crcmod,
            crc_check=p.crc_check,
            delimiter=p.delimiter,
        )
    ]
    if p.usb:
        L.append("# USB identity of a USB CDC-ACM station ([usb] in protocol.toml)")
        for k, v in p.usb.items():
            L.append(f"USB_{k.upper()}: Final = {v!r}" if isinstance(v, str) else f"USB_{k.upper()}: Final = 0x{int(v):04X}")
        L.append("")
    L.append("# header flags")
    for k, v in p.flags.items():
        L.append(f"FLAG_{k.upper()}: Final = 0x{v:02X}")
    L.append("\n# message type ranges (inclusive)")
    L.append("TYPE_RANGES: Final[dict[str, tuple[int, int]]] = {")
    for k, (lo, hi) in p.ranges.items():
        L.append(f"    {k!r}: (0x{lo:02X}, 0x{hi:02X}),")
    L.append("}")
    L.append(f"STREAM_TYPES: Final = range(0x{p.stream_types[0]:02X}, 0x{p.stream_types[1] + 1:02X})")
    L.append("\n# message types")
    for m in p.messages:
        L.append(f"T_{m.name.upper()}: Final = 0x{m.type:02X}  # {m.doc}")
    L.append("MESSAGE_NAMES: Final[dict[int, str]] = {")
    for m in p.messages:
        L.append(f"    0x{m.type:02X}: {m.name!r},")
    L.append("}")
    L.append("\n# error codes")
    for k, (c, d) in p.errors.items():
        L.append(f"ERR_{k.upper()}: Final = {c}  # {d}")
    L.append("ERROR_NAMES: Final[dict[int, str]] = {")
    for k, (c, _) in p.errors.items():
        L.append(f"    {c}: {k!r},")
    L.append("}")
    L.append("ERROR_DOCS: Final[dict[int, str]] = {")
    for _k, (c, d) in p.errors.items():
        L.append(f"    {c}: {d!r},")
    L.append("}")
    L += py_constants(p.constants)
    L += py_enums(p.enums)
    # structs
    for s in struct_order(p):
        cn = camel(s.name)
        L += ["", "@dataclass(frozen=True)", f"class {cn}(WireStruct):", f'    """{s.doc}"""', ""]
        for f in s.fields:
            a, d = _py_annot(f)
            L.append(f"    {f.name}: {a} = {d}  # {f.doc}" + (f" [{f.unit}]" if f.unit else ""))
        L += [
            f"    NAME: ClassVar[str] = {s.name!r}",
            f"    WIRE_SIZE: ClassVar[int] = {s.size}",
            f"    _S: ClassVar[struct.Struct] = struct.Struct({'<' + struct_format(s.fields, p)!r})",
            "",
            "    def _values(self) -> list[Any]:",
            f"        return [{', '.join(_py_values(s.fields))}]",
            "",
            "    @classmethod",
            "    def _from_values(cls, v: tuple[Any, ...]) -> Self:",
            f"        return cls({', '.join(_py_from_values(s.fields, p))})",
            "",
            "    @staticmethod",
            "    def _np_fields() -> list[Any]:",
            f"        return {_py_np_fields(s.fields)}",
            "",
        ]
    # messages: responses first so requests can name them
    reqs: dict[int, str] = {}
    resps: dict[int, str] = {}
    for m in p.messages:
        parts = msg_parts(m)
        parts.sort(key=lambda x: 0 if x[0] == "resp" else 1)
        for d, fields in parts:
            cn = camel(m.name) + ("Req" if d == "req" else "Resp")
            direction = "request" if d == "req" else "response"
            (reqs if d == "req" else resps)[m.type] = cn
            has_resp = d == "req" and not m.posted
            base = f"Request[{camel(m.name)}Resp]" if has_resp else "Message"
            fixed = [f for f in fields if f.t.kind not in ("tail", "tail_struct")]
            tail = fields[-1] if fields and fields[-1].t.kind in ("tail", "tail_struct") else None
            fixed_size = sum(f.t.size for f in fixed)
            L += [
                "",
                "@dataclass(frozen=True)",
                f"class {cn}({base}):",
                f'    """{m.name} {direction}: {m.doc}"""',
                "",
            ]
            for f in fields:
                a, dflt = _py_annot(f)
                L.append(f"    {f.name}: {a} = {dflt}  # {f.doc}" + (f" [{f.unit}]" if f.unit else ""))
            L += [
                f"    TYPE: ClassVar[int] = 0x{m.type:02X}",
                f"    NAME: ClassVar[str] = {m.name!r}",
                f"    DIRECTION: ClassVar[str] = {direction!r}",
                f"    FIELDS: ClassVar[tuple[str, ...]] = ({''.join(repr(f.name) + ', ' for f in fields)})",
                f"    FIXED_SIZE: ClassVar[int] = {fixed_size}",
                f"    _S: ClassVar[struct.Struct] = struct.Struct({'<' + struct_format(fixed, p)!r})",
            ]
            if tail is not None:
                if tail.t.kind == "tail":
                    L.append(f"    TAIL_MAX: ClassVar[int] = {tail_max(p, fields)}  # bytes")
                else:
                    L.append(f"    TAIL_MAX: ClassVar[int] = {tail_max(p, fields)}  # records")
            L.append("")
            if has_resp:
                L += [
                    f"    def response_class(self) -> type[{camel(m.name)}Resp]:",
                    f"        return {camel(m.name)}Resp",
                    "",
                ]
            L += [
                "    def encode(self) -> _Bytes:",
                f'        """The payload bytes ({direction})."""',
                f"        out = _pack(self._S, self.NAME, {', '.join(_py_values(fixed))})",
            ]
            if tail is not None and tail.t.kind == "tail":
                L += [
                    f"        if len(self.{tail.name}) > self.TAIL_MAX:",
                    f'            raise ValueError(f"{tail.name}: at most {{self.TAIL_MAX}} bytes")',
                    f"        out += bytes(self.{tail.name})",
                ]
            elif tail is not None:
                L += [
                    f"        if len(self.{tail.name}) > self.TAIL_MAX:",
                    f'            raise ValueError(f"{tail.name}: at most {{self.TAIL_MAX}} records")',
                    f'        out += b"".join(r.encode() for r in self.{tail.name})',
                ]
            L += [
                "        return out",
                "",
                "    @classmethod",
                "    def decode(cls, data: _Bytes) -> Self:",
                '        """Decode a payload; ProtocolError when its length is wrong."""',
            ]
            if tail is None:
                L += [
                    "        if len(data) != cls.FIXED_SIZE:",
                    "            raise cls._bad_length(len(data))",
                ]
            elif tail.t.kind == "tail":
                L += [
                    "        if not cls.FIXED_SIZE <= len(data) <= cls.FIXED_SIZE + cls.TAIL_MAX:",
                    "            raise cls._bad_length(len(data))",
                ]
            else:
                sc = camel(tail.t.base)
                L += [
                    "        rest = len(data) - cls.FIXED_SIZE",
                    f"        if rest < 0 or rest % {sc}.WIRE_SIZE or rest // {sc}.WIRE_SIZE > cls.TAIL_MAX:",
                    "            raise cls._bad_length(len(data))",
                ]
            args = _py_from_values(fixed, p)
            if fixed:
                L.append("        v = cls._S.unpack_from(data, 0)")
            if tail is not None and tail.t.kind == "tail":
                args.append(f"{tail.name}=bytes(data[cls.FIXED_SIZE:])")
            elif tail is not None:
                sc = camel(tail.t.base)
                args.append(
                    f"{tail.name}=tuple({sc}.decode(data, o) for o in range(cls.FIXED_SIZE, len(data), {sc}.WIRE_SIZE))"
                )
            L.append(f"        return cls({', '.join(args)})")
            L.append("")
    L.append("\n#: Request class per message type (dispatched and tunnel requests).")
    L.append("REQUESTS: Final[dict[int, type[Message]]] = {")
    for t, cn in sorted(reqs.items()):
        L.append(f"    0x{t:02X}: {cn},")
    L.append("}")
    L.append("#: Response class per message type (responses, streamed records, ERROR).")
    L.append("RESPONSES: Final[dict[int, type[Message]]] = {")
    for t, cn in sorted(resps.items()):
        L.append(f"    0x{t:02X}: {cn},")
    L.append("}")
    L.append("#: Struct class per struct name.")
    L.append("STRUCTS: Final[dict[str, type[WireStruct]]] = {")
    for s in sorted(p.structs):
        L.append(f"    {s!r}: {camel(s)},")
    L.append("}")
    L.append("#: Types the station dispatches (others: streamed, posted, tunnel, ERROR).")
    L.append(
        "DISPATCHED: Final[frozenset[int]] = frozenset({"
        + ", ".join(f"0x{m.type:02X}" for m in dispatched(p))
        + "})"
    )
    return "\n".join(L).rstrip() + "\n"


# ---------------------------------------------------------------------------------------------
