"""Shared calibration-table vectors: tests/firmware/test_table_vectors.json drives this file and
tests/firmware/test_table_apply.c, so the host and the station agree on validation (which
field is bad) and on the corrected range (mm, exactly).

Regenerate (only when the format or the arithmetic changes on purpose):
    .venv/bin/python tests/unit/test_table_vectors.py --write
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ulps import json_mismatch
from uwbcal import dw1000, tables
from uwbcal.corrections.power import PowerCurve
from uwbcal.errors import TableError
from uwbcal.link.proto_gen import CalTable

VECTORS = Path(__file__).resolve().parents[1] / "firmware" / "test_table_vectors.json"
UID_TAG = bytes.fromhex("0a0b0c0d0e0f101112131415")
UID_REF = bytes.fromhex("a1a2a3a4a5a6a7a8a9aaabac")
MOD = dw1000.TIMESTAMP_MOD


def _tables() -> tuple[bytes, bytes]:
    tag_curve = PowerCurve(
        measured_dbm=(-105.0, -95.5, -90.0, -85.25, -81.0, -78.0, -76.5),
        error_s=(210e-12, 120e-12, 40e-12, 0.0, -95e-12, -230e-12, -310e-12),
        real_dbm=(-105.0, -95.5, -90.0, -85.0, -79.5, -73.0, -66.0),
        reference_real_dbm=-66.0, reference_measured_dbm=-76.5)
    ref_curve = PowerCurve(
        measured_dbm=tuple(-110.0 + 2.5 * i for i in range(14)),
        error_s=tuple(3e-12 * (i - 6) ** 2 - 150e-12 + 11e-12 * i for i in range(14)),
        real_dbm=tuple(-110.0 + 2.7 * i for i in range(14)),
        reference_real_dbm=-75.0, reference_measured_dbm=-77.5)
    tag = tables.build(UID_TAG, tag_curve, z_ps=-1234.5, created_unix=1_763_769_600, host_version="0.1.0")
    ref = tables.build(UID_REF, ref_curve, z_ps=-987.25, created_unix=1_763_769_601, host_version="0.1.0")
    return tag, ref


def _reseal(data: bytes, **changes: Any) -> bytes:
    return tables.seal(dataclasses.replace(CalTable.decode(data), **changes))


def _set(seq: tuple[float, ...], i: int, v: float) -> tuple[float, ...]:
    return seq[:i] + (v,) + seq[i + 1:]


def _invalid(tag: bytes) -> list[dict[str, Any]]:
    t = CalTable.decode(tag)
    f = tables.FIELD_NAMES.index
    nan, inf = float("nan"), float("inf")
    cases: list[tuple[str, bytes, str, bytes | None]] = [
        ("bad crc", tag[:-1] + bytes([tag[-1] ^ 1]), "crc32", None),
        ("flipped bit, crc kept", tag[:100] + bytes([tag[100] ^ 0x10]) + tag[101:], "crc32", None),
        ("format 2", _reseal(tag, format_version=2), "format_version", None),
        ("other uid", tag, "uid", UID_REF),
        ("channel 6", _reseal(tag, channel=6), "channel", None),
        ("prf 32", _reseal(tag, prf_mhz=32), "prf_mhz", None),
        ("preamble 100", _reseal(tag, preamble_len=100), "preamble_len", None),
        ("data rate 3", _reseal(tag, data_rate=3), "data_rate", None),
        ("one curve point", _reseal(tag, n_curve=1), "n_curve", None),
        ("33 curve points", _reseal(tag, n_curve=33), "n_curve", None),
        ("one map point", _reseal(tag, n_map=1), "n_map", None),
        ("host version not ascii", _reseal(tag, host_version="v\u00e9"), "host_version", None),
        ("z NaN", _reseal(tag, z_ps=nan), "z_ps", None),
        ("z inf", _reseal(tag, z_ps=inf), "z_ps", None),
        ("z 2 us", _reseal(tag, z_ps=2e6), "z_ps", None),
        ("curve level NaN", _reseal(tag, curve_dbm=_set(t.curve_dbm, 3, nan)), "curve_dbm", None),
        ("curve level not increasing", _reseal(tag, curve_dbm=_set(t.curve_dbm, 2, t.curve_dbm[1])),
         "curve_dbm", None),
        ("curve level above 0 dBm", _reseal(tag, curve_dbm=_set(t.curve_dbm, t.n_curve - 1, 3.0)),
         "curve_dbm", None),
        ("curve level below -120 dBm", _reseal(tag, curve_dbm=_set(t.curve_dbm, 0, -121.0)),
         "curve_dbm", None),
        ("unused curve point set", _reseal(tag, curve_dbm=_set(t.curve_dbm, 31, -1.0)), "curve_dbm", None),
        ("curve error NaN", _reseal(tag, curve_ps=_set(t.curve_ps, 0, nan)), "curve_ps", None),
        ("curve error 6 ns", _reseal(tag, curve_ps=_set(t.curve_ps, 4, 6000.0)), "curve_ps", None),
        ("curve error -6 ns", _reseal(tag, curve_ps=_set(t.curve_ps, 4, -6000.0)), "curve_ps", None),
        ("unused curve error set", _reseal(tag, curve_ps=_set(t.curve_ps, 20, 1.0)), "curve_ps", None),
        ("map measured not increasing",
         _reseal(tag, map_measured_dbm=_set(t.map_measured_dbm, 1, -110.0)), "map_measured_dbm", None),
        ("map real decreasing", _reseal(tag, map_real_dbm=_set(t.map_real_dbm, 3, -100.0)),
         "map_real_dbm", None),
        ("map real NaN", _reseal(tag, map_real_dbm=_set(t.map_real_dbm, 0, nan)), "map_real_dbm", None),
        ("reserved set", _reseal(tag, reserved=b"\x00" * 7 + b"\x01"), "reserved", None),
        ("A NaN", _reseal(tag, a_dbm=nan), "a_dbm", None),
        ("A 140", _reseal(tag, a_dbm=140.0), "a_dbm", None),
        ("flags set", _reseal(tag, flags=1), "flags", None),
    ]
    return [{"name": n, "hex": d.hex(), "field": f(fld), "field_name": fld,
             "uid": None if u is None else u.hex()} for n, d, fld, u in cases]


def _exchange(rng: np.random.Generator, dist_m: float, start: int, eps_ppm: float, e1_ps: float,
              e2_ps: float, z_ps: float) -> list[int]:
    """Timestamps of one exchange at dist_m: tag clock (1+eps) t + phase, RX stamps late by E and
    early by z (split: the total hardware offset is -z)."""
    u = dw1000.TIME_UNIT_S
    tof = dist_m / dw1000.C_LIGHT
    eps = eps_ppm * 1e-6
    e1, e2, zz = e1_ps * 1e-12, e2_ps * 1e-12, z_ps * 1e-12
    t1 = start * u
    t2 = t1 + 300e-6 + float(rng.uniform(0, 1e-6))
    t3 = t2 + 300e-6
    phase = float(rng.uniform(0, 17.0))

    def tag_clock(t: float) -> int:
        return round(((1 + eps) * t + phase) / u) % MOD

    def ref_clock(t: float) -> int:
        return round(t / u) % MOD

    # M1 ref->tag (RX at the tag late by E1), M2 tag->ref (RX late by E2), M3 ref->tag (late by E1)
    # -2 z of round trip (Z is added back); tag TX at tag time t2 - tof
    t1r = ref_clock(t1)
    t1t = tag_clock(t1 + tof - zz + e1 / (1 + eps))
    t2t = tag_clock(t2 - tof)
    t2r = ref_clock(t2 - zz + e2)
    t3r = ref_clock(t3)
    t3t = tag_clock(t3 + tof - zz + e1 / (1 + eps))
    return [t1r, t1t, t2t, t2r, t3r, t3t]


def _ranges(tag: bytes, ref: bytes) -> list[dict[str, Any]]:
    rng = np.random.default_rng(5)
    tt, rt = CalTable.decode(tag), CalTable.decode(ref)
    out: list[dict[str, Any]] = []
    cases = [
        ("3 m", 3.0, 123_456_789, 12.0, (3000, 1024), (2900, 1024)),
        ("0.56 m, strong", 0.562, 10_000_000, -7.5, (30000, 900), (31000, 1000)),
        ("wrap between M1 and M2", 1.8, MOD - 2_000_000, 20.0, (1500, 1024), (1700, 1024)),
        ("wrap of the tag clock", 2.5, MOD // 2, -15.0, (800, 1024), (640, 1024)),
        ("weak, below both curves", 9.0, 77_777_777, 3.0, (20, 1024), (15, 1024)),
        ("at a curve point", 4.0, 5_000_000_000, 0.0, (0, 0), (5000, 1000)),
        ("no level: CIR_PWR 0", 4.0, 5_000_000_000, 0.0, (0, 1024), (5000, 1000)),
        ("far, 40 m", 40.0, 900_000_000_000, 9.0, (120, 1024), (110, 1024)),
    ]
    for name, dist, start, ppm, q1, q2 in cases:
        if name == "at a curve point":
            # choose CIR_PWR so that the tag's level lands near its point 3 (-85.25 dBm)
            c = float(dw1000.cir_pwr_for_level(tt.curve_dbm[3], 1024, a_dbm=tt.a_dbm))
            q1 = (round(c), 1024)
        e1 = tables.error_ps(tt, *q1)
        e2 = tables.error_ps(rt, *q2)
        z = float(tt.z_ps) + float(rt.z_ps)
        t6 = _exchange(rng, dist, start, ppm, e1 or 0.0, e2 or 0.0, z)
        mm = tables.station_range_mm(t6, tt, rt, q1, q2)
        out.append({"name": name, "distance_m": dist, "t": t6, "q_t1": list(q1), "q_r2": list(q2),
                    "e1_ps": e1, "e2_ps": e2, "range_mm": mm})
    return out


def make_vectors() -> dict[str, Any]:
    """The vector document (deterministic)."""
    tag, ref = _tables()
    return {
        "doc": ("Calibration-table vectors shared by tests/unit/test_table_vectors.py and "
                "tests/firmware/test_table_apply.c. tables[0] is the tag's, tables[1] the reference's. "
                "invalid: field = index of the first bad cal_table field (uid checked against `uid` "
                "when given). ranges: t = t1r t1t t2t t2r t3r t3t (device units), q = [CIR_PWR, RXPACC], "
                "e1_ps from the tag's table (sent as f32), e2_ps from the reference's, range_mm = the "
                "reference's corrected range with Z = z_tag + z_ref; null = no range."),
        "table_size": tables.TABLE_SIZE,
        "tables": [{"name": "tag", "uid": UID_TAG.hex(), "hex": tag.hex()},
                   {"name": "ref", "uid": UID_REF.hex(), "hex": ref.hex()}],
        "invalid": _invalid(tag),
        "ranges": _ranges(tag, ref),
    }


@pytest.fixture(scope="module")
def vec() -> dict[str, Any]:
    doc: dict[str, Any] = json.loads(VECTORS.read_text())
    return doc


def test_file_is_current(vec: dict[str, Any]) -> None:
    """The checked-in vectors are what the host computes today (same tables, same ranges):
    integers and bytes identical, floats (E1, E2: log10 and interpolation) within a few ULPs,
    as another CPU's libm may round them (tests/unit/ulps.py)."""
    why = json_mismatch(vec, json.loads(json.dumps(make_vectors())))
    assert why is None, why


def test_range_vectors_are_clear_of_rounding_boundaries(vec: dict[str, Any]) -> None:
    """Each stored range (whole mm, rounded from a float chain with log10 in it) is at least
    3e-5 mm from a half-millimetre boundary, so no CPU's last-bit rounding can flip it: moving
    Z by 1e-4 ps (3e-5 mm) either way gives the same millimetre."""
    tag, ref = (tables.decode(bytes.fromhex(t["hex"])) for t in vec["tables"][:2])
    checked = 0
    for r in vec["ranges"]:
        if r["range_mm"] is None:
            continue
        z = float(tag.z_ps) + float(ref.z_ps)
        e1 = float(np.float32(r["e1_ps"]))
        for dz in (-1e-4, 1e-4):
            assert tables.range_mm(r["t"], e1, r["e2_ps"], z + dz) == r["range_mm"], r["name"]
        checked += 1
    assert checked >= 6


def test_tables_valid(vec: dict[str, Any]) -> None:
    for t in vec["tables"]:
        data = bytes.fromhex(t["hex"])
        assert len(data) == vec["table_size"] == tables.TABLE_SIZE
        assert tables.problem(data, bytes.fromhex(t["uid"])) is None


def test_invalid_named(vec: dict[str, Any]) -> None:
    assert len(vec["invalid"]) >= 25
    for case in vec["invalid"]:
        data = bytes.fromhex(case["hex"])
        uid = None if case["uid"] is None else bytes.fromhex(case["uid"])
        p = tables.problem(data, uid)
        assert p is not None, case["name"]
        assert p[0] == case["field"], (case["name"], p)
        with pytest.raises(TableError, match=f"table field {case['field_name']}"):
            tables.check(data, uid)


def test_ranges_recover_distance(vec: dict[str, Any]) -> None:
    """Independent of the stored numbers: the corrected range is the true distance (+- 1 cm,
    timestamps are rounded to 15.65 ps), whatever the clocks, the wrap, E1, E2 and Z."""
    tag, ref = (CalTable.decode(bytes.fromhex(t["hex"])) for t in vec["tables"])
    n_checked = 0
    for r in vec["ranges"]:
        mm = tables.station_range_mm(r["t"], tag, ref, tuple(r["q_t1"]), tuple(r["q_r2"]))
        assert mm == r["range_mm"], r["name"]
        if r["range_mm"] is None:
            assert r["q_t1"][0] == 0 or r["q_r2"][0] == 0
            continue
        assert mm is not None and abs(mm / 1000.0 - r["distance_m"]) < 0.01, r["name"]
        n_checked += 1
    assert n_checked >= 6


def test_corrections_matter(vec: dict[str, Any]) -> None:
    """Leaving out E1/E2/Z moves the range: the vectors exercise every term."""
    tag, ref = (CalTable.decode(bytes.fromhex(t["hex"])) for t in vec["tables"])
    r = vec["ranges"][0]
    full = tables.range_mm(r["t"], r["e1_ps"], r["e2_ps"], tag.z_ps + ref.z_ps)
    assert full is not None
    for e1, e2, z in ((0.0, r["e2_ps"], tag.z_ps + ref.z_ps), (r["e1_ps"], 0.0, tag.z_ps + ref.z_ps),
                      (r["e1_ps"], r["e2_ps"], 0.0)):
        other = tables.range_mm(r["t"], e1, e2, z)
        assert other is not None and abs(other - full) >= 5


def test_error_interpolation_clamps(vec: dict[str, Any]) -> None:
    tag = CalTable.decode(bytes.fromhex(vec["tables"][0]["hex"]))
    n = tag.n_curve
    lo = float(dw1000.cir_pwr_for_level(tag.curve_dbm[0] - 10, 1024, a_dbm=tag.a_dbm))
    hi = float(dw1000.cir_pwr_for_level(tag.curve_dbm[n - 1] + 5, 1024, a_dbm=tag.a_dbm))
    assert tables.error_ps(tag, max(1, round(lo)), 1024) == pytest.approx(tag.curve_ps[0])
    assert tables.error_ps(tag, round(hi), 1024) == pytest.approx(tag.curve_ps[n - 1])
    assert tables.error_ps(tag, 0, 1024) is None
    assert not math.isnan(tables.error_ps(tag, 3000, 1024) or math.nan)


if __name__ == "__main__":
    if "--write" in sys.argv:
        VECTORS.write_text(json.dumps(make_vectors(), indent=1) + "\n")
        print(f"wrote {VECTORS}")
    else:
        print(__doc__)


def test_error_corrects_rxpacc_when_not_saturated(vec: dict[str, Any]) -> None:
    """RXPACC == RXPACC_NOSAT: N = RXPACC - 5 at 6.8 Mb/s (user manual; caltable_rxpacc_n)."""
    tag = CalTable.decode(bytes.fromhex(vec["tables"][0]["hex"]))
    n = tag.n_curve
    mid = 0.5 * (tag.curve_dbm[0] + tag.curve_dbm[n - 1])  # inside the curve: not clamped
    c = round(float(dw1000.cir_pwr_for_level(mid, 200, a_dbm=tag.a_dbm)))
    corr = {0: 64, 1: 5, 2: 5}[tag.data_rate]
    same = tables.error_ps(tag, c, 200, 200)
    assert same == pytest.approx(tables.error_ps(tag, c, 200 - corr))
    assert same != pytest.approx(tables.error_ps(tag, c, 200))
    assert tables.error_ps(tag, c, 200, 208) == tables.error_ps(tag, c, 200)
