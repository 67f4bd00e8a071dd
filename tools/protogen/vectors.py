"""Test-vector output: protocol/vectors.json as C tables in tests/firmware/vectors_gen.h."""

# ruff: noqa: E501  (templates of generated lines, kept whole to stay readable)
from __future__ import annotations

import json

from protogen.model import (
    BANNER,
    SCALARS,
    Field,
    Protocol,
    ProtocolDefError,
)

# Vectors


def _c_bytes(name: str, hexstr: str) -> tuple[str, int]:
    data = bytes.fromhex(hexstr)
    if not data:
        return f"static const uint8_t {name}[1] = {{0}};", 0
    body = ", ".join(f"0x{b:02X}" for b in data)
    lines = []
    chunk = 16
    items = body.split(", ")
    for i in range(0, len(items), chunk):
        lines.append("    " + ", ".join(items[i : i + chunk]) + ",")
    return f"static const uint8_t {name}[{len(data)}] = {{\n" + "\n".join(lines) + "\n};", len(data)


def _c_str(s: str) -> str:
    return json.dumps(s)


def _c_field_checks(
    fields: list[Field], values: dict[str, object], obj: str, p: Protocol, lines: list[str]
) -> None:
    if set(values) != {f.name for f in fields}:
        raise ProtocolDefError(f"vectors: fields {sorted(values)} do not match {[f.name for f in fields]}")
    for f in fields:
        v = values[f.name]
        x = f"{obj}.{f.name}"
        t = f.t
        if t.kind == "scalar":
            if t.base.startswith("f"):
                lines.append(f"    bad += !({x} == ({SCALARS[t.base][2]}){float(v)!r});")  # type: ignore[arg-type]
            elif t.base.startswith("i"):
                lines.append(f"    bad += !({x} == (int64_t){int(v)}LL);")  # type: ignore[call-overload]
            else:
                lines.append(f"    bad += !({x} == (uint64_t){int(v)}ULL);")  # type: ignore[call-overload]
        elif t.kind == "array":
            for i, e in enumerate(v):  # type: ignore[arg-type]
                if t.base.startswith("f"):
                    lines.append(f"    bad += !({x}[{i}] == ({SCALARS[t.base][2]}){float(e)!r});")
                else:
                    lines.append(
                        f"    bad += !((int64_t){x}[{i}] == (int64_t){int(e)}LL);"
                        if t.base.startswith("i")
                        else f"    bad += !({x}[{i}] == (uint64_t){int(e)}ULL);"
                    )
        elif t.kind == "bytes":
            data = bytes.fromhex(str(v)).ljust(t.n, b"\0")
            arr = ", ".join(f"0x{b:02X}" for b in data)
            lines.append(
                f"    {{ static const uint8_t e[{t.n}] = {{{arr}}}; bad += memcmp({x}, e, {t.n}) != 0; }}"
            )
        elif t.kind == "str":
            lines.append(f"    bad += strcmp({x}, {_c_str(str(v))}) != 0;")
        elif t.kind == "struct":
            _c_field_checks(p.structs[t.base].fields, v, x, p, lines)  # type: ignore[arg-type]
        elif t.kind == "struct_array":
            for i, e in enumerate(v):  # type: ignore[arg-type]
                _c_field_checks(p.structs[t.base].fields, e, f"{x}[{i}]", p, lines)
        elif t.kind == "tail":
            data = bytes.fromhex(str(v))
            arr = ", ".join(f"0x{b:02X}" for b in data) or "0"
            lines.append(
                f"    {{ static const uint8_t e[{max(1, len(data))}] = {{{arr}}}; "
                f"bad += {x}_len != {len(data)}u || memcmp({x}, e, {len(data)}) != 0; }}"
            )
        else:
            lines.append(f"    bad += {x}_count != {len(v)}u;")  # type: ignore[arg-type]
            lines.append(f"    if ({x}_count == {len(v)}u) {{")  # type: ignore[arg-type]
            for i, e in enumerate(v):  # type: ignore[arg-type]
                _c_field_checks(p.structs[t.base].fields, e, f"{x}[{i}]", p, lines)
            lines.append("    }")


def _c_table(struct: str, name: str, rows: list[str], count: str) -> list[str]:
    """A static const array of vector rows and its count macro."""
    return [f"static const struct {struct} {name}[] = {{", *rows, "};", f"#define {count} {len(rows)}u", ""]


def gen_vectors_h(p: Protocol, vec: dict[str, object]) -> str:
    L = [
        f"/* {BANNER} Source: protocol/vectors.json. */",
        "#ifndef UWBCAL_VECTORS_GEN_H",
        "#define UWBCAL_VECTORS_GEN_H",
        "",
        "#include <stddef.h>",
        "#include <stdint.h>",
        "#include <string.h>",
        "",
        '#include "proto_gen.h"',
        "",
        "struct crc_vector { const char *name; const uint8_t *data; size_t len; uint32_t crc; };",
        "struct cobs_vector { const char *name; const uint8_t *decoded; size_t decoded_len; const uint8_t *encoded; size_t encoded_len; };",
        "struct frame_vector {",
        "    const char *name;",
        "    const uint8_t *wire; size_t wire_len;       /* COBS-encoded, with the trailing 0x00 */",
        "    const uint8_t *raw; size_t raw_len;         /* header | payload | crc */",
        "    uint8_t version, type, flags; uint16_t seq;",
        "    const uint8_t *payload; size_t payload_len;",
        "    uint32_t crc;",
        "    int is_request;                            /* 1 request, 0 response/stream/error */",
        "    int (*check_fields)(const uint8_t *payload, size_t len); /* mismatches, -1 if undecodable */",
        "    int response;                              /* index of the expected response vector, -1 none */",
        "};",
        "struct malformed_vector {",
        "    const char *name;",
        "    const uint8_t *wire; size_t wire_len;       /* bytes sent, ending with 0x00 */",
        "    uint8_t code, request_type; uint16_t detail; uint16_t seq; /* the expected ERROR */",
        "    const uint8_t *response; size_t response_len; /* the expected ERROR frame on the wire */",
        "};",
        "",
    ]
    crcs = vec["crc"]
    cobs_v = vec["cobs"]
    frames = vec["frames"]
    malformed = vec["malformed"]
    assert (
        isinstance(crcs, list)
        and isinstance(cobs_v, list)
        and isinstance(frames, list)
        and isinstance(malformed, list)
    )
    rows = []
    for i, c in enumerate(crcs):
        d, n = _c_bytes(f"crc_data_{i}", c["data"])
        L.append(d)
        rows.append(f"    {{{_c_str(c['name'])}, crc_data_{i}, {n}u, 0x{int(c['crc'], 16):08X}u}},")
    L += _c_table("crc_vector", "crc_vectors", rows, "N_CRC_VECTORS")
    rows = []
    for i, c in enumerate(cobs_v):
        d, n = _c_bytes(f"cobs_dec_{i}", c["decoded"])
        e, m = _c_bytes(f"cobs_enc_{i}", c["encoded"])
        L += [d, e]
        rows.append(f"    {{{_c_str(c['name'])}, cobs_dec_{i}, {n}u, cobs_enc_{i}, {m}u}},")
    L += _c_table("cobs_vector", "cobs_vectors", rows, "N_COBS_VECTORS")
    names = {f["name"]: i for i, f in enumerate(frames)}
    by_name = {m.name: m for m in p.messages}
    rows = []
    for i, f in enumerate(frames):
        w, wn = _c_bytes(f"frame_wire_{i}", f["wire"])
        r, rn = _c_bytes(f"frame_raw_{i}", f["raw"])
        pl, pn = _c_bytes(f"frame_payload_{i}", f["payload"])
        L += [w, r, pl]
        m = by_name[f["message"]]
        d = "req" if f["direction"] == "request" else "resp"
        fields = m.request if d == "req" else m.response
        L += [
            f"static int frame_check_{i}(const uint8_t *payload, size_t len)",
            "{",
            f"    static struct proto_{m.name}_{d} m;",
            "    int bad = 0;",
            f"    if (proto_{m.name}_{d}_decode(payload, len, &m) != 0) return -1;",
        ]
        checks: list[str] = []
        _c_field_checks(fields, f["fields"], "m", p, checks)
        L += checks
        L += ["    return bad;", "}"]
        hdr = f["header"]
        resp = names[f["response"]] if f.get("response") else -1
        rows.append(
            f"    {{{_c_str(f['name'])}, frame_wire_{i}, {wn}u, frame_raw_{i}, {rn}u, {hdr['version']}u, "
            f"0x{hdr['type']:02X}u, 0x{hdr['flags']:02X}u, {hdr['seq']}u, frame_payload_{i}, {pn}u, "
            f"0x{int(f['crc'], 16):08X}u, {1 if f['direction'] == 'request' else 0}, frame_check_{i}, {resp}}},"
        )
    L += _c_table("frame_vector", "frame_vectors", rows, "N_FRAME_VECTORS")
    rows = []
    for i, mv in enumerate(malformed):
        w, wn = _c_bytes(f"bad_wire_{i}", mv["wire"])
        r, rn = _c_bytes(f"bad_resp_{i}", mv["response"])
        L += [w, r]
        e = mv["error"]
        code = p.errors[e["code"]][0]
        rows.append(
            f"    {{{_c_str(mv['name'])}, bad_wire_{i}, {wn}u, {code}u, {e['request_type']}u, {e['detail']}u, "
            f"{e['seq']}u, bad_resp_{i}, {rn}u}},"
        )
    L += _c_table("malformed_vector", "malformed_vectors", rows, "N_MALFORMED_VECTORS")
    L += ["#endif", ""]
    return "\n".join(L)


# ---------------------------------------------------------------------------------------------
# PROTOCOL.md reference section
