"""C output: firmware/core/proto_gen.h and proto_gen.c (structs, codecs, dispatch)."""

# ruff: noqa: E501  (templates of generated lines, kept whole to stay readable)
from __future__ import annotations

from protogen.layout import dispatched, msg_parts, struct_order, tail_max
from protogen.model import (
    BANNER,
    SCALARS,
    Constant,
    Enum,
    Field,
    Protocol,
)


def _c_comment(text: str, indent: str = "") -> str:
    return f"{indent}/* {text.replace('*/', '* /')} */"


def _c_member(f: Field, macro_prefix: str) -> list[str]:
    t = f.t
    doc = f.doc + (f" [{f.unit}]" if f.unit else "")
    c = _c_comment(doc)
    if t.kind == "scalar":
        return [f"    {SCALARS[t.base][2]} {f.name}; {c}"]
    if t.kind == "array":
        return [f"    {SCALARS[t.base][2]} {f.name}[{t.n}]; {c}"]
    if t.kind == "bytes":
        return [f"    uint8_t {f.name}[{t.n}]; {c}"]
    if t.kind == "str":
        return [
            f"    char {f.name}[{t.n + 1}]; {_c_comment(doc + '; NUL-terminated here, NUL-padded on the wire')}"
        ]
    if t.kind == "struct":
        return [f"    struct proto_{t.base} {f.name}; {c}"]
    if t.kind == "struct_array":
        return [f"    struct proto_{t.base} {f.name}[{t.n}]; {c}"]
    mx = f"{macro_prefix}_{f.name.upper()}_MAX"
    if t.kind == "tail":
        return [
            f"    uint8_t {f.name}[{mx}]; {c}",
            f"    uint16_t {f.name}_len; /* bytes used in {f.name} */",
        ]
    return [
        f"    struct proto_{t.base} {f.name}[{mx}]; {c}",
        f"    uint16_t {f.name}_count; /* records used in {f.name} */",
    ]


_PUT = {1: "wire_put_u8", 2: "wire_put_u16", 4: "wire_put_u32", 8: "wire_put_u64"}
_GET = {1: "wire_get_u8", 2: "wire_get_u16", 4: "wire_get_u32", 8: "wire_get_u64"}
_UT = {1: "uint8_t", 2: "uint16_t", 4: "uint32_t", 8: "uint64_t"}


def _c_put_scalar(base: str, expr: str, at: str) -> str:
    size, _, ctype = SCALARS[base]
    if base == "f32":
        return f"wire_put_f32({at}, {expr});"
    if base == "f64":
        return f"wire_put_f64({at}, {expr});"
    return f"{_PUT[size]}({at}, ({_UT[size]}){expr});"


def _c_get_scalar(base: str, at: str) -> str:
    size, _, ctype = SCALARS[base]
    if base == "f32":
        return f"wire_get_f32({at})"
    if base == "f64":
        return f"wire_get_f64({at})"
    return f"({ctype}){_GET[size]}({at})"


def _c_fields(fields: list[Field], obj: str, p: Protocol, encode: bool) -> list[str]:
    """The statements that encode (``encode``) or decode the fields of ``obj`` at ``b + o``,
    advancing ``o``: one ladder for both directions, so that they cannot drift apart."""
    out: list[str] = []
    for f in fields:
        t, x = f.t, f"{obj}->{f.name}"
        step = f"{t.size}u"
        if t.kind == "scalar":
            one = _c_put_scalar(t.base, x, "b + o") if encode else f"{x} = {_c_get_scalar(t.base, 'b + o')};"
        elif t.kind == "array":
            w = SCALARS[t.base][0]
            el = (_c_put_scalar(t.base, x + "[i]", "b + o") if encode
                  else f"{x}[i] = {_c_get_scalar(t.base, 'b + o')};")
            out.append(f"    for (size_t i = 0; i < {t.n}u; i++) {{ {el} o += {w}u; }}")
            continue
        elif t.kind == "bytes":
            one = f"memcpy(b + o, {x}, {t.n}u);" if encode else f"memcpy({x}, b + o, {t.n}u);"
        elif t.kind == "str":
            one = f"wire_put_str(b + o, {x}, {t.n}u);" if encode else f"wire_get_str({x}, b + o, {t.n}u);"
        elif t.kind in ("struct", "struct_array", "tail_struct"):
            sz = p.structs[t.base].size
            call = (f"proto_{t.base}_encode(&{x}{{i}}, b + o);" if encode
                    else f"proto_{t.base}_decode(b + o, &{x}{{i}});")
            if t.kind == "struct":
                out += [f"    {call.format(i='')}", f"    o += {sz}u;"]
                continue
            if t.kind == "tail_struct" and not encode:
                out.append(f"    {x}_count = (uint16_t)((len - o) / {sz}u);")
            n = f"{t.n}u" if t.kind == "struct_array" else f"{x}_count"
            out.append(f"    for (size_t i = 0; i < {n}; i++) {{ {call.format(i='[i]')} o += {sz}u; }}")
            continue
        else:  # tail
            if not encode:
                out.append(f"    {x}_len = (uint16_t)(len - o);")
            one = (f"if ({x}_len > 0u) memcpy(b + o, {x}, {x}_len);" if encode
                   else f"if ({x}_len > 0u) memcpy({x}, b + o, {x}_len);")
            step = f"{x}_len"
        out += [f"    {one}", f"    o += {step};"]
    return out


def _c_number(type_: str, v: int | float) -> str:
    if type_.startswith("f"):
        s = repr(float(v)) + ("f" if type_ == "f32" else "")
    elif type_.startswith("i"):
        bits = SCALARS[type_][0] * 8
        # the most negative value as C's limits.h writes it: a plain literal would not be an int
        s = f"-{2 ** (bits - 1) - 1} - 1" if int(v) == -(2 ** (bits - 1)) else str(int(v))
    else:
        s = f"0x{int(v):08X}u" if int(v) > 0xFFFF else f"{int(v)}u"
    return f"({s})" if s.startswith("-") else s


def c_constants(consts: dict[str, Constant], prefix: str) -> list[str]:
    """#defines of [[constant]]s; a list value gives NAME_COUNT and NAME_VALUES (an initialiser)."""
    if not consts:
        return []
    L = ["", "/* ---- constants ---- */"]
    for c in consts.values():
        note = _c_comment(c.doc + (f" [{c.unit}]" if c.unit else ""))
        n = f"{prefix}{c.name.upper()}"
        if isinstance(c.value, tuple):
            L.append(f"#define {n}_COUNT {len(c.value)}u {note}")
            L.append(f"#define {n}_VALUES {{{', '.join(_c_number(c.type, v) for v in c.value)}}}")
        else:
            L.append(f"#define {n} {_c_number(c.type, c.value)} {note}")
    return L


def c_enums(enums: dict[str, Enum], prefix: str) -> list[str]:
    """#defines of [[enum]] values: PREFIX_ENUM_VALUE."""
    L: list[str] = []
    for e in enums.values():
        L += ["", _c_comment(f"{e.name}: {e.doc}")]
        for v in e.values:
            val = f"0x{v.value:02X}u" if e.bits else f"{v.value}u"
            L.append(f"#define {prefix}{e.name.upper()}_{v.name.upper()} {val} {_c_comment(v.doc)}")
    return L


def gen_c_header(p: Protocol) -> str:
    L: list[str] = [
        f"/* {BANNER} */",
        "#ifndef UWBCAL_PROTO_GEN_H",
        "#define UWBCAL_PROTO_GEN_H",
        "",
        "#include <stddef.h>",
        "#include <stdint.h>",
        "",
        "/* ---- framing ---- */",
        f"#define PROTO_VERSION {p.version}u",
        f"#define PROTO_MAX_PAYLOAD {p.max_payload}u /* bytes, payload only */",
        f"#define PROTO_HEADER_SIZE {p.header_size}u /* version u8, type u8, flags u8, seq u16 */",
        "#define PROTO_CRC_SIZE 4u",
        f'#define PROTO_CRC_CHECK 0x{p.crc_check:08X}u /* {p.crc_name} of "123456789" */',
        f"#define PROTO_DELIMITER 0x{p.delimiter:02X}u",
        "#define PROTO_FRAME_MAX (PROTO_HEADER_SIZE + PROTO_MAX_PAYLOAD + PROTO_CRC_SIZE) /* decoded */",
        "#define PROTO_DETAIL_NONE 0xFFFFu",
        "",
    ]
    if p.usb:
        L.append("/* ---- USB identity of a USB CDC-ACM station ([usb] in protocol.toml) ---- */")
        for k, v in p.usb.items():
            if isinstance(v, str):
                L.append(f'#define PROTO_USB_{k.upper()} "{v}"')
            else:
                L.append(f"#define PROTO_USB_{k.upper()} 0x{int(v):04X}u")
        L.append("")
    L.append("/* ---- header flags ---- */")
    for k, v in p.flags.items():
        L.append(f"#define PROTO_FLAG_{k.upper()} 0x{v:02X}u")
    L += ["", "/* ---- message type ranges ---- */"]
    for k, (lo, hi) in p.ranges.items():
        L.append(f"#define PROTO_RANGE_{k.upper()}_FIRST 0x{lo:02X}u")
        L.append(f"#define PROTO_RANGE_{k.upper()}_LAST 0x{hi:02X}u")
    L.append(f"#define PROTO_STREAM_FIRST 0x{p.stream_types[0]:02X}u /* streamed record types */")
    L.append(f"#define PROTO_STREAM_LAST 0x{p.stream_types[1]:02X}u")
    L += ["", "/* ---- message types ---- */"]
    for m in p.messages:
        L.append(f"#define PROTO_T_{m.name.upper()} 0x{m.type:02X}u {_c_comment(m.doc)}")
    L += ["", "/* ---- error codes (the ERROR message's code) ---- */"]
    for k, (c, d) in p.errors.items():
        L.append(f"#define PROTO_ERR_{k.upper()} {c} {_c_comment(d)}")
    L += c_constants(p.constants, "PROTO_")
    L += c_enums(p.enums, "PROTO_")
    L += [
        "",
        "struct proto_header {",
        "    uint8_t version;",
        "    uint8_t type;",
        "    uint8_t flags;",
        "    uint16_t seq;",
        "};",
        "void proto_header_encode(const struct proto_header *h, uint8_t b[PROTO_HEADER_SIZE]);",
        "void proto_header_decode(const uint8_t b[PROTO_HEADER_SIZE], struct proto_header *h);",
        'const char *proto_error_name(int code);      /* "bad_crc", or "?" */',
        'const char *proto_message_name(int type);    /* "ping", or "?" */',
        "",
    ]
    L.append("/* ---- structs (fixed wire size, little-endian, no padding on the wire) ---- */")
    for s in struct_order(p):
        L.append(_c_comment(s.doc))
        L.append(f"#define PROTO_{s.name.upper()}_WIRE_SIZE {s.size}u")
        L.append(f"struct proto_{s.name} {{")
        for f in s.fields:
            L += _c_member(f, f"PROTO_{s.name.upper()}")
        L.append("};")
        L.append(
            f"void proto_{s.name}_encode(const struct proto_{s.name} *s, uint8_t *b); /* writes WIRE_SIZE bytes */"
        )
        L.append(
            f"void proto_{s.name}_decode(const uint8_t *b, struct proto_{s.name} *s); /* reads WIRE_SIZE bytes */"
        )
        L.append("")
    L.append("/* ---- messages: encode returns 0 or PROTO_ERR_BAD_LENGTH (buffer too small, tail too long);")
    L.append(" * decode returns 0 or PROTO_ERR_BAD_LENGTH (payload length wrong for the message). ---- */")
    for m in p.messages:
        for d, fields in msg_parts(m):
            mp = f"PROTO_{m.name.upper()}_{d.upper()}"
            fixed = sum(f.t.size for f in fields)
            L.append(_c_comment(f"{m.name} {'request' if d == 'req' else 'response'}: {m.doc}"))
            L.append(f"#define {mp}_FIXED_SIZE {fixed}u")
            if fields and fields[-1].t.kind in ("tail", "tail_struct"):
                L.append(f"#define {mp}_{fields[-1].name.upper()}_MAX {tail_max(p, fields)}u")
            L.append(f"struct proto_{m.name}_{d} {{")
            if not fields:
                L.append("    uint8_t reserved_; /* no fields: C needs one member */")
            for f in fields:
                L += _c_member(f, mp)
            L.append("};")
            L.append(
                f"int proto_{m.name}_{d}_encode(const struct proto_{m.name}_{d} *m, uint8_t *b, size_t cap, size_t *len);"
            )
            L.append(
                f"int proto_{m.name}_{d}_decode(const uint8_t *b, size_t len, struct proto_{m.name}_{d} *m);"
            )
            L.append("")
    L += [
        "/* ---- request handlers ----",
        " * Each returns 0 after filling *resp (zeroed before the call), or a PROTO_ERR_* code with",
        " * *detail set (the offending field's index for bad_value, else what the code's doc says).",
        " * Core handlers are defined in firmware/core; the others have weak defaults in",
        " * proto_gen.c answering unknown_type, overridden by the module that implements them. */",
    ]
    for m in dispatched(p):
        L.append(
            f"int handle_{m.name}(const struct proto_{m.name}_req *req, struct proto_{m.name}_resp *resp, uint16_t *detail); /* {m.role} */"
        )
    L += [
        "",
        "/* Decode the payload of a request of `type`, call its handler, encode the response payload",
        " * into out[0..cap). Returns 0 with *out_len set, or a PROTO_ERR_* code with *detail set",
        " * (unknown_type: detail = type; bad_length: detail = payload length). Not reentrant. */",
        "int proto_dispatch(uint8_t type, const uint8_t *payload, size_t len, uint8_t *out, size_t cap,",
        "                   size_t *out_len, uint16_t *detail);",
        "",
        "#endif",
        "",
    ]
    return "\n".join(L)


def gen_c_source(p: Protocol) -> str:
    body: list[str] = []
    body += [
        "void proto_header_encode(const struct proto_header *h, uint8_t b[PROTO_HEADER_SIZE])",
        "{",
        "    b[0] = h->version;",
        "    b[1] = h->type;",
        "    b[2] = h->flags;",
        "    wire_put_u16(b + 3, h->seq);",
        "}",
        "",
        "void proto_header_decode(const uint8_t b[PROTO_HEADER_SIZE], struct proto_header *h)",
        "{",
        "    h->version = b[0];",
        "    h->type = b[1];",
        "    h->flags = b[2];",
        "    h->seq = wire_get_u16(b + 3);",
        "}",
        "",
        "const char *proto_error_name(int code)",
        "{",
        "    switch (code) {",
    ]
    for k, (c, _) in p.errors.items():
        body.append(f'    case {c}: return "{k}";')
    body += [
        '    default: return "?";',
        "    }",
        "}",
        "",
        "const char *proto_message_name(int type)",
        "{",
        "    switch (type) {",
    ]
    for m in p.messages:
        body.append(f'    case 0x{m.type:02X}: return "{m.name}";')
    body += ['    default: return "?";', "    }", "}", ""]
    for s in struct_order(p):
        enc = _c_fields(s.fields, "s", p, True)
        dec = _c_fields(s.fields, "s", p, False)
        body += [
            f"void proto_{s.name}_encode(const struct proto_{s.name} *s, uint8_t *b)",
            "{",
            "    size_t o = 0;",
            *enc,
            "    (void)o;",
            "}",
            "",
            f"void proto_{s.name}_decode(const uint8_t *b, struct proto_{s.name} *s)",
            "{",
            "    size_t o = 0;",
            *dec,
            "    (void)o;",
            "}",
            "",
        ]
    for m in p.messages:
        for d, fields in msg_parts(m):
            mp = f"PROTO_{m.name.upper()}_{d.upper()}"
            sn = f"proto_{m.name}_{d}"
            tail = fields[-1] if fields and fields[-1].t.kind in ("tail", "tail_struct") else None
            body += [
                f"int {sn}_encode(const struct {sn} *m, uint8_t *b, size_t cap, size_t *len)",
                "{",
                f"    size_t need = {mp}_FIXED_SIZE;",
            ]
            if tail is not None:
                mx = f"{mp}_{tail.name.upper()}_MAX"
                if tail.t.kind == "tail":
                    body += [
                        f"    if (m->{tail.name}_len > {mx}) return PROTO_ERR_BAD_LENGTH;",
                        f"    need += m->{tail.name}_len;",
                    ]
                else:
                    sz = p.structs[tail.t.base].size
                    body += [
                        f"    if (m->{tail.name}_count > {mx}) return PROTO_ERR_BAD_LENGTH;",
                        f"    need += (size_t)m->{tail.name}_count * {sz}u;",
                    ]
            body += ["    if (need > cap) return PROTO_ERR_BAD_LENGTH;", "    size_t o = 0;"]
            if not fields:
                body += ["    (void)m;", "    (void)b;"]
            body += _c_fields(fields, "m", p, True)
            body += ["    *len = o;", "    return 0;", "}", ""]
            body += [f"int {sn}_decode(const uint8_t *b, size_t len, struct {sn} *m)", "{"]
            if tail is None:
                body += [f"    if (len != {mp}_FIXED_SIZE) return PROTO_ERR_BAD_LENGTH;"]
            elif tail.t.kind == "tail":
                lo = f"len < {mp}_FIXED_SIZE || " if sum(f.t.size for f in fields) else ""
                body += [
                    f"    if ({lo}len - {mp}_FIXED_SIZE > {mp}_{tail.name.upper()}_MAX)",
                    "        return PROTO_ERR_BAD_LENGTH;",
                ]
            else:
                sz = p.structs[tail.t.base].size
                lo = f"len < {mp}_FIXED_SIZE || " if sum(f.t.size for f in fields) else ""
                body += [
                    f"    if ({lo}(len - {mp}_FIXED_SIZE) % {sz}u != 0u",
                    f"        || (len - {mp}_FIXED_SIZE) / {sz}u > {mp}_{tail.name.upper()}_MAX)",
                    "        return PROTO_ERR_BAD_LENGTH;",
                ]
            body += ["    size_t o = 0;"]
            if not fields:
                body += ["    (void)m;", "    (void)b;"]
            body += _c_fields(fields, "m", p, False)
            body += ["    (void)o;", "    return 0;", "}", ""]
    # weak default handlers
    for m in dispatched(p):
        if m.role != "weak":
            continue
        body += [
            f"__attribute__((weak)) int handle_{m.name}(const struct proto_{m.name}_req *req,",
            f"                                     struct proto_{m.name}_resp *resp, uint16_t *detail)",
            "{",
            "    (void)req;",
            "    (void)resp;",
            f"    *detail = PROTO_T_{m.name.upper()};",
            "    return PROTO_ERR_UNKNOWN_TYPE;",
            "}",
            "",
        ]
    # dispatch
    body += [
        "int proto_dispatch(uint8_t type, const uint8_t *payload, size_t len, uint8_t *out, size_t cap,",
        "                   size_t *out_len, uint16_t *detail)",
        "{",
        "    static union {",
    ]
    for m in dispatched(p):
        body.append(f"        struct proto_{m.name}_req {m.name};")
    body += ["    } req;", "    static union {"]
    for m in dispatched(p):
        body.append(f"        struct proto_{m.name}_resp {m.name};")
    body += ["    } resp;", "    int rc;", "    *out_len = 0;", "    switch (type) {"]
    for m in dispatched(p):
        n = m.name
        body += [
            f"    case PROTO_T_{n.upper()}:",
            f"        if (proto_{n}_req_decode(payload, len, &req.{n}) != 0) {{",
            "            *detail = (uint16_t)(len > 0xFFFFu ? 0xFFFFu : len);",
            "            return PROTO_ERR_BAD_LENGTH;",
            "        }",
            "        memset(&resp, 0, sizeof resp);",
            f"        rc = handle_{n}(&req.{n}, &resp.{n}, detail);",
            "        if (rc != 0) return rc;",
            f"        rc = proto_{n}_resp_encode(&resp.{n}, out, cap, out_len);",
            "        if (rc != 0) *detail = PROTO_DETAIL_NONE;",
            "        return rc;",
        ]
    body += [
        "    default:",
        "        *detail = type;",
        "        return PROTO_ERR_UNKNOWN_TYPE;",
        "    }",
        "}",
        "",
    ]
    text = "\n".join(body)
    return "\n".join(
        [
            f"/* {BANNER} */",
            '#include "proto_gen.h"',
            "",
            "#include <string.h>",
            "",
            '#include "proto_wire.h"',
            "",
            text,
        ]
    )


# ---------------------------------------------------------------------------------------------
# Python
