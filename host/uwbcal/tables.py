"""Calibration tables: build, validate, store as JSON, push to / pull from a station, and the
host's recomputation of the range a station computes with its table.

The format is the ``cal_table`` struct of protocol/messages/tables.toml (generated into
:class:`uwbcal.link.proto_gen.CalTable`): exactly :data:`TABLE_SIZE` bytes, little-endian, the
last field a CRC-32/ISO-HDLC of every byte before it. The bytes are the table: a T.json file
holds them in hex (``"bytes"``) beside a readable copy of the fields; push sends those bytes,
pull returns the bytes from flash, so push -> restart -> pull compares byte for byte.

Validation (:func:`check`) applies the same rules, in the same order, as the firmware's
``caltable_validate`` (firmware/core/caltable.c); both run on the shared vectors in
tests/firmware/test_table_vectors.json. Bounds: RX levels -120 .. 0 dBm, curve errors within
+-5 ns, the z share within +-1 us, A within 100 .. 130 dBm.

Units: RX levels dBm; timestamp errors and z in ps (``error_s`` of a
:class:`~uwbcal.corrections.power.PowerCurve` times 1e12); ranges mm.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import struct
import time
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final, Protocol, TypeVar

import numpy as np

from uwbcal import __version__, dw1000
from uwbcal.corrections import twr
from uwbcal.corrections.power import PowerCurve
from uwbcal.errors import DeviceTimeout, ProtocolError, TableError
from uwbcal.link import proto_gen as pg
from uwbcal.link.proto_gen import CalTable

#: Bytes of one table (the cal_table struct).
TABLE_SIZE: Final = CalTable.WIRE_SIZE
# Format version, limits and slot states: constants of protocol/messages/tables.toml; radio
# settings: the chip's (protocol/dw1000.toml). The firmware's caltable.c checks the same
# generated values.
#: Format version this host writes and accepts.
FORMAT_VERSION: Final = pg.TABLE_FORMAT_VERSION
#: Points of the curve and of the power map.
MAX_POINTS: Final = pg.TABLE_MAX_POINTS
#: Field names in wire order: ERROR bad_value's detail for table_commit is an index into this.
FIELD_NAMES: Final = tuple(f.name for f in dataclasses.fields(CalTable))
#: table_commit's bad_value detail with this bit set names the commit request's own field.
DETAIL_REQUEST: Final = pg.TABLE_DETAIL_REQUEST
DBM_MIN: Final = pg.TABLE_DBM_MIN
DBM_MAX: Final = pg.TABLE_DBM_MAX
ERR_PS_MAX: Final = pg.TABLE_ERR_PS_MAX
Z_PS_MAX: Final = pg.TABLE_Z_PS_MAX
A_MIN: Final = pg.TABLE_A_MIN
A_MAX: Final = pg.TABLE_A_MAX
CHANNELS: Final = dw1000.CHANNELS
PRFS: Final = dw1000.PRFS
PREAMBLES: Final = dw1000.PREAMBLE_LENGTHS
#: Largest chunk of a table_write / table_read this host sends or asks for (bytes).
CHUNK: Final = 256
assert CHUNK <= pg.TABLE_READ_MAX
SLOT_STATES: Final = pg.TABLE_SLOT_STATE_NAMES


def field_at(offset: int) -> str:
    """Name of the cal_table field holding byte ``offset`` (from the generated wire layout)."""
    pos = 0
    for name, code in zip(FIELD_NAMES, re.findall(r"\d*[a-zA-Z?]", CalTable._S.format.lstrip("<")),
                          strict=True):
        pos += struct.calcsize("<" + code)
        if offset < pos:
            return name
    return "(past the end)"


def crc32(data: bytes) -> int:
    """CRC-32/ISO-HDLC (zlib's CRC-32) of ``data``."""
    return zlib.crc32(data) & 0xFFFFFFFF


def seal(t: CalTable) -> bytes:
    """The table's bytes with its crc32 field set."""
    body = dataclasses.replace(t, crc32=0).encode()[:-4]
    return body + crc32(body).to_bytes(4, "little")


def decode(data: bytes) -> CalTable:
    """The fields of a table's bytes (no checks beyond the size)."""
    if len(data) != TABLE_SIZE:
        raise TableError(f"a table is {TABLE_SIZE} bytes, got {len(data)}")
    return CalTable.decode(data)


def _f32(x: float) -> float:
    return float(np.float32(x))


def _axis_problem(x: Sequence[float], n: int, lo: float, hi: float, strict: bool) -> str | None:
    for i, v in enumerate(x):
        if i >= n:
            if v != 0.0:
                return f"unused point {i} is {v}, must be 0"
            continue
        if math.isnan(v):
            return f"point {i} is NaN"
        if not lo <= v <= hi:
            return f"point {i} = {v:g} outside {lo:g} .. {hi:g}"
        if i > 0 and (not v > x[i - 1] if strict else not v >= x[i - 1]):
            order = "strictly increasing" if strict else "non-decreasing"
            return f"point {i} = {v:g} after {x[i - 1]:g}: not {order}"
    return None


def problem(data: bytes, uid: bytes | None = None) -> tuple[int, str] | None:
    """The first bad field of a table as (index in FIELD_NAMES, what is wrong), or None.

    The same checks in the same order as the firmware; ``uid`` None skips the uid check.
    """
    if len(data) != TABLE_SIZE:
        return 0, f"a table is {TABLE_SIZE} bytes, got {len(data)}"
    t = CalTable.decode(data)
    idx = FIELD_NAMES.index
    if crc32(data[:-4]) != t.crc32:
        return idx("crc32"), f"CRC 0x{t.crc32:08X} does not match the contents (0x{crc32(data[:-4]):08X})"
    if t.format_version != FORMAT_VERSION:
        return idx("format_version"), f"format version {t.format_version}, this host knows {FORMAT_VERSION}"
    if uid is not None and t.uid != bytes(uid):
        return idx("uid"), f"made for station {t.uid.hex()}, this station is {bytes(uid).hex()}"
    if t.channel not in CHANNELS:
        return idx("channel"), f"channel {t.channel} is not one of {CHANNELS}"
    if t.prf_mhz not in PRFS:
        return idx("prf_mhz"), f"PRF {t.prf_mhz} MHz is not 16 or 64"
    if t.preamble_len not in PREAMBLES:
        return idx("preamble_len"), f"preamble length {t.preamble_len} is not one of {PREAMBLES}"
    if t.data_rate > 2:
        return idx("data_rate"), f"data rate code {t.data_rate} is not 0, 1 or 2"
    if not 2 <= t.n_curve <= MAX_POINTS:
        return idx("n_curve"), f"{t.n_curve} curve points, need 2 .. {MAX_POINTS}"
    if t.n_map == 1 or t.n_map > MAX_POINTS:
        return idx("n_map"), f"{t.n_map} power map points, need 0 or 2 .. {MAX_POINTS}"
    if not all(" " <= c <= "~" for c in t.host_version) or t.encode() != data:
        return idx("host_version"), "host_version is not NUL-padded printable ASCII"
    if math.isnan(t.z_ps) or not -Z_PS_MAX <= t.z_ps <= Z_PS_MAX:
        return idx("z_ps"), f"z share {t.z_ps} ps outside +-{Z_PS_MAX:g} ps"
    p = _axis_problem(t.curve_dbm, t.n_curve, DBM_MIN, DBM_MAX, True)
    if p:
        return idx("curve_dbm"), p
    for i, v in enumerate(t.curve_ps):
        if i < t.n_curve and (math.isnan(v) or not -ERR_PS_MAX <= v <= ERR_PS_MAX):
            return idx("curve_ps"), f"point {i} = {v} ps outside +-{ERR_PS_MAX:g} ps (or NaN)"
        if i >= t.n_curve and v != 0.0:
            return idx("curve_ps"), f"unused point {i} is {v}, must be 0"
    p = _axis_problem(t.map_measured_dbm, t.n_map, DBM_MIN, DBM_MAX, True)
    if p:
        return idx("map_measured_dbm"), p
    p = _axis_problem(t.map_real_dbm, t.n_map, DBM_MIN, DBM_MAX, False)
    if p:
        return idx("map_real_dbm"), p
    if any(t.reserved):
        return idx("reserved"), "reserved bytes must be 0"
    if math.isnan(t.a_dbm) or not A_MIN <= t.a_dbm <= A_MAX:
        return idx("a_dbm"), f"A = {t.a_dbm} dBm outside {A_MIN:g} .. {A_MAX:g}"
    if t.flags != 0:
        return idx("flags"), f"flags 0x{t.flags:X}, must be 0"
    return None


def check(data: bytes, uid: bytes | None = None) -> CalTable:
    """The decoded table, or :class:`TableError` naming the first bad field."""
    p = problem(data, uid)
    if p is not None:
        raise TableError(f"table field {FIELD_NAMES[p[0]]}: {p[1]}")
    return CalTable.decode(data)


def _pad(values: Sequence[float], n: int = MAX_POINTS) -> tuple[float, ...]:
    return tuple(_f32(v) for v in values) + (0.0,) * (n - len(values))


def _thin(n: int, keep: int = MAX_POINTS) -> list[int]:
    """Indices of at most ``keep`` of n points, evenly spread, both ends kept."""
    if n <= keep:
        return list(range(n))
    return sorted({round(i * (n - 1) / (keep - 1)) for i in range(keep)})


def build(uid: bytes, curve: PowerCurve, *, channel: int = 2, prf_mhz: int = 64, preamble_len: int = 128,
          data_rate: int = 2, z_ps: float = 0.0, a_dbm: float | None = None, created_unix: int | None = None,
          host_version: str = __version__, tx_antd: int = 0, rx_antd: int = 0) -> bytes:
    """A sealed, checked table from a power curve (``error_s`` in s, axes in dBm).

    More than 32 curve points are thinned evenly (ends kept). ``z_ps`` is this station's share of
    Z (ps): Z = z_ref + z_tag, so half of a pair's Z goes to each station. ``a_dbm`` defaults to
    the user manual's A for the PRF (the A the curve's measured axis was computed with).
    """
    if len(uid) != 12:
        raise TableError(f"station uid must be 12 bytes, got {len(uid)}")
    a = dw1000.RX_LEVEL_A_DBM[prf_mhz] if a_dbm is None and prf_mhz in dw1000.RX_LEVEL_A_DBM else a_dbm
    keep = _thin(len(curve.measured_dbm))
    meas = [curve.measured_dbm[i] for i in keep]
    err_ps = [curve.error_s[i] * 1e12 for i in keep]
    real = [curve.real_dbm[i] for i in keep]
    n_map = len(keep) if len(keep) >= 2 else 0
    t = CalTable(
        format_version=FORMAT_VERSION, uid=bytes(uid), channel=channel, prf_mhz=prf_mhz,
        preamble_len=preamble_len, data_rate=data_rate, n_curve=len(keep), n_map=n_map,
        created_unix=int(time.time()) if created_unix is None else created_unix,
        host_version=host_version.encode("utf-8")[:16].decode("utf-8", "ignore"),
        tx_antd=tx_antd, rx_antd=rx_antd, z_ps=_f32(z_ps),
        curve_dbm=_pad(meas), curve_ps=_pad(err_ps),
        map_measured_dbm=_pad(meas if n_map else []), map_real_dbm=_pad(real if n_map else []),
        reserved=bytes(8), a_dbm=_f32(float("nan") if a is None else a), flags=0, crc32=0)
    data = seal(t)
    check(data)
    return data


# --- JSON files ---------------------------------------------------------------------------------

def to_json(data: bytes, validity: dict[str, Any] | None = None) -> dict[str, Any]:
    """A T.json document: the bytes in hex (authoritative), a readable copy of the fields and,
    when given, the calibration's ``validity`` (corrections/validity.py: the swept span and the
    level estimate's trusted region)."""
    t = decode(data)
    fields: dict[str, Any] = {}
    for name in FIELD_NAMES:
        v = getattr(t, name)
        fields[name] = v.hex() if isinstance(v, bytes) else list(v) if isinstance(v, tuple) else v
    fields["curve_dbm"] = list(t.curve_dbm[:t.n_curve])
    fields["curve_ps"] = list(t.curve_ps[:t.n_curve])
    fields["map_measured_dbm"] = list(t.map_measured_dbm[:t.n_map])
    fields["map_real_dbm"] = list(t.map_real_dbm[:t.n_map])
    # strict JSON: a NaN or infinity (only in an invalid table) is written as null
    for k, v in fields.items():
        if isinstance(v, float) and not math.isfinite(v):
            fields[k] = None
        elif isinstance(v, list):
            fields[k] = [None if isinstance(x, float) and not math.isfinite(x) else x for x in v]
    doc = {"kind": "uwbcal calibration table", "format_version": t.format_version, "size": len(data),
           "bytes": data.hex(), "fields": fields,
           "note": "`bytes` is the table; `fields` is a readable copy and is not read back"}
    if validity is not None:
        doc["validity"] = validity
    return doc


def from_json(doc: dict[str, Any]) -> bytes:
    """The table bytes of a T.json document (the ``bytes`` member)."""
    try:
        data = bytes.fromhex(str(doc["bytes"]))
    except (KeyError, ValueError) as exc:
        raise TableError(f"not a table file: no valid `bytes` member ({exc})") from None
    decode(data)
    return data


def save(path: str | Path, data: bytes, validity: dict[str, Any] | None = None) -> None:
    """Write a T.json file (with the calibration's validity when given)."""
    Path(path).write_text(json.dumps(to_json(data, validity), indent=1) + "\n")


def curve_of(data: bytes, station: int | None = None) -> PowerCurve:
    """The power curve a table holds (its measured axis, errors in s, real power where mapped)."""
    t = decode(data)
    n = t.n_curve
    real = t.map_real_dbm[:n] if t.n_map == n else t.curve_dbm[:n]
    return PowerCurve(measured_dbm=tuple(t.curve_dbm[:n]), error_s=tuple(v * 1e-12 for v in t.curve_ps[:n]),
                      real_dbm=tuple(real), reference_real_dbm=float(real[-1]),
                      reference_measured_dbm=float(t.curve_dbm[n - 1]), rx_station=station)


def load_validity(path: str | Path) -> dict[str, Any] | None:
    """The ``validity`` member of a T.json file (None when absent, e.g. a raw or pulled table)."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    v = doc.get("validity") if isinstance(doc, dict) else None
    return v if isinstance(v, dict) else None


def load(path: str | Path) -> bytes:
    """Read a T.json file (or a raw table of TABLE_SIZE bytes)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise TableError(f"{p}: {exc.strerror}") from None
    if len(raw) == TABLE_SIZE and not raw.lstrip().startswith(b"{"):
        return raw
    try:
        doc = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise TableError(f"{p}: not JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise TableError(f"{p}: not a table file")
    return from_json(doc)


def describe(data: bytes) -> str:
    """A human-readable summary of a table (what `uwbcal table show` prints)."""
    t = decode(data)
    p = problem(data)
    when = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(t.created_unix))
    lines = [
        f"calibration table, format {t.format_version}, {len(data)} bytes, crc32 0x{t.crc32:08X}"
        + ("" if p is None else f"  INVALID: {FIELD_NAMES[p[0]]}: {p[1]}"),
        f"station uid   {t.uid.hex()}",
        f"radio         channel {t.channel}, PRF {t.prf_mhz} MHz, preamble {t.preamble_len}, "
        f"data rate code {t.data_rate}",
        f"created       {when} by uwbcal {t.host_version}",
        f"antenna delay tx {t.tx_antd} rx {t.rx_antd} device units (0 = keep)",
        f"z share       {t.z_ps:.1f} ps ({t.z_ps * 1e-12 * dw1000.C_LIGHT * 1000:.1f} mm)",
        f"A             {t.a_dbm:.2f} dBm",
        f"curve         {t.n_curve} points (measured dBm -> timestamp error ps):",
    ]
    # An invalid table may claim more points than it holds: show what it holds.
    n_curve = min(t.n_curve, len(t.curve_dbm), len(t.curve_ps))
    n_map = min(t.n_map, len(t.map_measured_dbm), len(t.map_real_dbm))
    for i in range(n_curve):
        real = f"  real {t.map_real_dbm[i]:7.2f} dBm" if i < n_map and t.n_map == t.n_curve else ""
        lines.append(f"  {t.curve_dbm[i]:8.2f} dBm  {t.curve_ps[i]:9.2f} ps{real}")
    if t.n_map and t.n_map != t.n_curve:
        lines.append(f"power map     {t.n_map} points (measured dBm -> real dBm):")
        lines += [f"  {t.map_measured_dbm[i]:8.2f} -> {t.map_real_dbm[i]:8.2f}" for i in range(n_map)]
    return "\n".join(lines)


# --- the corrections, as the station computes them ------------------------------------------------

def rx_level_dbm(cir_pwr: int, rxpacc: int, a_dbm: float) -> float | None:
    """Measured RX level (dBm) from CIR_PWR and N (RXPACC, corrected) with the table's A; None
    when C or N is 0."""
    if cir_pwr == 0 or rxpacc == 0:
        return None
    return float(dw1000.rx_level_dbm(cir_pwr, rxpacc, a_dbm=a_dbm))




def error_ps(t: CalTable, cir_pwr: int, rxpacc: int, rxpacc_nosat: int | None = None) -> float | None:
    """The station's timestamp error (ps, measured minus true) of one reception, from its table.

    RXPACC is corrected for the SFD when it equals RXPACC_NOSAT (the table's data rate), as
    the station's caltable_table_error_ps does; ``rxpacc_nosat`` None: RXPACC as read.
    """
    rates = dw1000.DATA_RATES_KBPS
    n = int(dw1000.rxpacc_n(rxpacc, rxpacc_nosat, rates[min(t.data_rate, len(rates) - 1)]))
    level = rx_level_dbm(cir_pwr, n, t.a_dbm)
    if level is None:
        return None
    n = t.n_curve
    return float(np.interp(level, t.curve_dbm[:n], t.curve_ps[:n]))


def _ps_to_units(ps: float) -> float:
    return ps * 1e-12 / dw1000.TIME_UNIT_S


def range_mm(t6: Sequence[int], e1_ps: float, e2_ps: float, z_ps: float) -> int | None:
    """The paper's corrected range (mm) from t1r t1t t2t t2r t3r t3t, E1, E2 and Z (ps).

    The same arithmetic as caltable_range_mm, through :func:`uwbcal.corrections.twr.paper_tof_units`.
    """
    t1r, t1t, t2t, t2r, t3r, t3t = (int(v) for v in t6)
    if dw1000.wrap_diff(t3t, t1t) == 0:
        return None
    tof = float(twr.paper_tof_units(t1r, t1t, t2t, t2r, t3r, t3t, _ps_to_units(e1_ps), _ps_to_units(e2_ps)))
    mm = math.floor((tof + _ps_to_units(z_ps)) * dw1000.METRES_PER_UNIT * 1000.0 + 0.5)
    if not -(2**31) < mm < 2**31:
        return None
    return int(mm)


def station_range_mm(t6: Sequence[int], tag: CalTable, ref: CalTable, q_t1: tuple[int, ...],
                     q_r2: tuple[int, ...]) -> int | None:
    """The range a reference reports with its table and the tag's reported share.

    ``q_t1`` is (CIR_PWR, RXPACC[, RXPACC_NOSAT]) of M1 at the tag, ``q_r2`` of M2 at the
    reference. The tag sends E1 rounded to f32, as the firmware does. None where the station reports no range.
    """
    e1 = error_ps(tag, *q_t1)
    e2 = error_ps(ref, *q_r2)
    if e1 is None or e2 is None:
        return None
    return range_mm(t6, _f32(e1), e2, float(ref.z_ps) + float(tag.z_ps))


# --- talking to a station -----------------------------------------------------------------------

R = TypeVar("R", bound=pg.Message)


class Requester(Protocol):
    """What these functions need of a station (:class:`uwbcal.link.client.Client` has it)."""

    def request(self, msg: pg.Request[R], /, *, timeout: float | None = None,
                retries: int | None = None) -> R:
        """Send ``msg``; its response, or a :class:`~uwbcal.errors.ProtocolError` on ERROR."""
        ...


#: Time a station may take to erase, program and verify a slot, s (STM32F1: about 40 ms).
COMMIT_TIMEOUT_S: Final = 5.0


def _commit_error(exc: ProtocolError) -> TableError | None:
    """A station's bad_value answer to table_commit as a TableError naming the table field."""
    code, detail = getattr(exc, "code", None), getattr(exc, "detail", None)
    if code != pg.ERR_BAD_VALUE or not isinstance(detail, int):
        return None
    if detail & DETAIL_REQUEST:
        what = {0: "length (the staged table is incomplete or of another size)",
                1: "crc32 (the staged bytes differ from the table)"}.get(detail & 0x7FFF, str(detail))
        return TableError(f"station refused the table: commit {what}")
    name = FIELD_NAMES[detail] if detail < len(FIELD_NAMES) else f"#{detail}"
    hint = " (made for another station; --force to push it anyway)" if name == "uid" else ""
    return TableError(f"station refused the table: field {name}{hint}")


def push(dev: Requester, data: bytes, *, uid: bytes | None = None, radio: tuple[int, int, int] | None = None,
         force: bool = False) -> pg.TableCommitResp:
    """Write a table to a station: checks, table_write chunks, table_commit.

    Refuses (:class:`TableError`, one line) a table for another ``uid`` or another ``radio``
    (channel, PRF MHz, preamble) unless ``force``; NaN, unordered axes and out-of-bounds values
    are refused always. The station checks again and answers bad_value with the field index.
    """
    t = check(data)
    if uid is not None and t.uid != bytes(uid) and not force:
        raise TableError(f"table is for station {t.uid.hex()}, this station is {bytes(uid).hex()} "
                         "(--force to push it anyway)")
    if radio is not None and (t.channel, t.prf_mhz, t.preamble_len) != tuple(radio) and not force:
        raise TableError(f"table is for channel {t.channel} PRF {t.prf_mhz} preamble {t.preamble_len}, "
                         f"the station runs channel {radio[0]} PRF {radio[1]} preamble {radio[2]} "
                         "(--force to push it anyway)")
    for off in range(0, len(data), CHUNK):
        r = dev.request(pg.TableWriteReq(offset=off, data=data[off:off + CHUNK]))
        if r.staged != min(off + CHUNK, len(data)):
            raise TableError(f"station staged {r.staged} bytes after the chunk at {off}")
    commit = pg.TableCommitReq(length=len(data), crc32=t.crc32, force=1 if force else 0)
    try:
        # a retry resends the same seq and bytes: the station answers it from its memory of the
        # last request without committing twice (PROTOCOL.md, Retries)
        return dev.request(commit, timeout=COMMIT_TIMEOUT_S)
    except DeviceTimeout:
        i = info(dev)   # the answer may be what got lost: is the table active now?
        if i.active != 0xFF and i.table_crc32 == t.crc32:
            seq = i.slot0_sequence if i.active == 0 else i.slot1_sequence
            return pg.TableCommitResp(slot=i.active, sequence=seq)
        raise
    except ProtocolError as exc:
        err = _commit_error(exc)
        if err is None:
            raise
        raise err from None


def pull(dev: Requester) -> bytes:
    """The station's active table, bytes as stored in flash (ProtocolError not_found if none)."""
    first = dev.request(pg.TableReadReq(offset=0, length=CHUNK))
    total = first.total
    out = bytearray(first.data)
    while len(out) < total:
        r = dev.request(pg.TableReadReq(offset=len(out), length=CHUNK))
        if not r.data or r.total != total:
            raise TableError(f"station's table changed or ended early while reading at {len(out)}")
        out += r.data
    return bytes(out)


def info(dev: Requester) -> pg.TableInfoResp:
    """Slot states, sequences, the active slot and its CRC."""
    return dev.request(pg.TableInfoReq())


def erase(dev: Requester) -> None:
    """Erase both slots of a station."""
    dev.request(pg.TableEraseReq())


def describe_info(i: pg.TableInfoResp) -> str:
    """One line per slot, for `uwbcal table info` and `verify`."""
    act = "none" if i.active == 0xFF else f"slot {i.active}"
    lines = [f"active table: {act}, crc32 0x{i.table_crc32:08X}, applied {bool(i.applied)}"]
    for s, st, seq in ((0, i.slot0_state, i.slot0_sequence), (1, i.slot1_state, i.slot1_sequence)):
        lines.append(f"slot {s}: {SLOT_STATES.get(st, f'state {st}')}, sequence {seq}")
    return "\n".join(lines)
