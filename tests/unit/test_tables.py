"""uwbcal.tables and `uwbcal table`: build from a session, JSON files, checks, and the push /
pull logic against a recording fake station (the real station: tests/hil/test_table_hil.py)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from uwbcal import cli, dw1000, tables
from uwbcal.corrections.power import PowerCurve
from uwbcal.errors import DeviceTimeout, TableError
from uwbcal.link import proto_gen as pg
from uwbcal.link.client import ErrorResponse

UID = bytes.fromhex("00112233445566778899aabb")


def _curve(n: int = 6) -> PowerCurve:
    m = tuple(float(x) for x in np.linspace(-105.0, -75.0, n))
    return PowerCurve(measured_dbm=m, error_s=tuple(-8e-12 * (x + 90.0) for x in m),
                      real_dbm=tuple(x + max(0.0, x + 85.0) for x in m),
                      reference_real_dbm=-70.0, reference_measured_dbm=-75.0)


def test_build_round_trip(tmp_path: Path) -> None:
    data = tables.build(UID, _curve(), z_ps=-321.5, created_unix=1_700_000_000, host_version="9.8.7")
    assert len(data) == tables.TABLE_SIZE == 581
    t = tables.check(data, UID)
    assert t.n_curve == t.n_map == 6 and t.uid == UID and t.z_ps == -321.5
    assert (t.channel, t.prf_mhz, t.preamble_len, t.data_rate) == (2, 64, 128, 2)
    assert t.a_dbm == pytest.approx(dw1000.RX_LEVEL_A_DBM[64])
    assert t.curve_ps[0] == pytest.approx(-8 * (-105 + 90), abs=1e-3)
    assert t.curve_dbm[6:] == (0.0,) * 26
    tables.save(tmp_path / "t.json", data)
    doc = json.loads((tmp_path / "t.json").read_text())
    assert doc["fields"]["host_version"] == "9.8.7" and len(doc["fields"]["curve_dbm"]) == 6
    assert tables.load(tmp_path / "t.json") == data
    (tmp_path / "t.bin").write_bytes(data)
    assert tables.load(tmp_path / "t.bin") == data
    # the readable copy is not read back: the bytes are the table
    doc["fields"]["z_ps"] = 0.0
    (tmp_path / "t2.json").write_text(json.dumps(doc))
    assert tables.load(tmp_path / "t2.json") == data


def test_build_thins_long_curves_keeping_ends() -> None:
    data = tables.build(UID, _curve(47), created_unix=0)
    t = tables.decode(data)
    assert t.n_curve == 32
    assert t.curve_dbm[0] == -105.0 and t.curve_dbm[31] == -75.0


def test_build_refuses_bad_curves() -> None:
    c = _curve()
    with pytest.raises(TableError, match="curve_ps"):
        tables.build(UID, dataclasses.replace(c, error_s=(float("nan"),) + c.error_s[1:]))
    with pytest.raises(TableError, match="curve_ps"):
        tables.build(UID, dataclasses.replace(c, error_s=(7e-9,) + c.error_s[1:]))
    with pytest.raises(TableError, match="curve_dbm"):
        tables.build(UID, dataclasses.replace(c, measured_dbm=(-130.0,) + c.measured_dbm[1:]))
    with pytest.raises(TableError, match="z_ps"):
        tables.build(UID, c, z_ps=5e6)
    with pytest.raises(TableError, match="12 bytes"):
        tables.build(UID[:6], c)


def test_load_errors_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(TableError, match="No such file"):
        tables.load(tmp_path / "missing.json")
    (tmp_path / "x.json").write_text('{"bytes": "zz"}')
    with pytest.raises(TableError, match="not a table file"):
        tables.load(tmp_path / "x.json")
    (tmp_path / "y.json").write_text('{"bytes": "00"}')
    with pytest.raises(TableError, match="581 bytes"):
        tables.load(tmp_path / "y.json")


def test_show_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tables.build(UID, _curve(), created_unix=1_700_000_000)
    tables.save(tmp_path / "t.json", data)
    assert cli.main(["table", "show", str(tmp_path / "t.json")]) == 0
    out = capsys.readouterr().out
    assert UID.hex() in out and "6 points" in out and "INVALID" not in out
    bad = tables.seal(dataclasses.replace(tables.decode(data), a_dbm=float("nan")))
    tables.save(tmp_path / "bad.json", bad)
    assert cli.main(["table", "show", str(tmp_path / "bad.json")]) == TableError.exit_code   # shown, refused
    assert "INVALID: a_dbm" in capsys.readouterr().out


def test_field_at_follows_the_layout() -> None:
    data = tables.build(UID, _curve(), created_unix=0)
    t = tables.decode(data)
    for name in ("uid", "z_ps", "curve_ps", "a_dbm", "crc32"):
        # flip a byte of every field in turn: decoding shows which field changed
        for off in range(tables.TABLE_SIZE):
            if tables.field_at(off) == name:
                mod = bytearray(data)
                mod[off] ^= 0x01
                changed = [f for f in tables.FIELD_NAMES
                           if repr(getattr(tables.decode(bytes(mod)), f)) != repr(getattr(t, f))]
                assert changed == [name]
                break
        else:
            raise AssertionError(name)


# --- push / pull against a fake station ----------------------------------------------------------

def _err(type_: int, code: int, detail: int) -> ErrorResponse:
    return ErrorResponse("fake", type_, pg.ErrorResp(code=code, request_type=type_, detail=detail))


class FakeStation:
    """Records requests; holds staged bytes and one table; can answer ERROR or time out."""

    def __init__(self) -> None:
        self.sent: list[Any] = []
        self.staged = bytearray()
        self.table: bytes | None = None
        self.commit_error: int | None = None
        self.commit_timeout = False

    def request(self, msg: Any, /, *, timeout: float | None = None, retries: int | None = None) -> Any:
        self.sent.append(msg)
        if isinstance(msg, pg.TableWriteReq):
            if msg.offset == 0:
                self.staged = bytearray()
            self.staged[msg.offset:msg.offset + len(msg.data)] = msg.data
            return pg.TableWriteResp(staged=len(self.staged))
        if isinstance(msg, pg.TableCommitReq):
            if self.commit_error is not None:
                raise _err(msg.TYPE, pg.ERR_BAD_VALUE, self.commit_error)
            self.table = bytes(self.staged)
            if self.commit_timeout:
                raise DeviceTimeout("fake: no answer")
            return pg.TableCommitResp(slot=0, sequence=1)
        if isinstance(msg, pg.TableReadReq):
            if self.table is None:
                raise _err(msg.TYPE, pg.ERR_NOT_FOUND, 0xFFFF)
            chunk = self.table[msg.offset:msg.offset + msg.length]
            return pg.TableReadResp(total=len(self.table), data=chunk)
        if isinstance(msg, pg.TableInfoReq):
            crc = 0 if self.table is None else tables.decode(self.table).crc32
            return pg.TableInfoResp(active=0xFF if self.table is None else 0, slot0_state=1, slot0_sequence=1,
                                    table_size=tables.TABLE_SIZE, table_crc32=crc, applied=1)
        raise AssertionError(msg)


def test_push_chunks_and_commits() -> None:
    dev = FakeStation()
    data = tables.build(UID, _curve(), created_unix=0)
    r = tables.push(dev, data, uid=UID, radio=(2, 64, 128))
    assert r.sequence == 1 and dev.table == data
    writes = [m for m in dev.sent if isinstance(m, pg.TableWriteReq)]
    assert [w.offset for w in writes] == [0, 256, 512]
    assert all(len(w.data) <= tables.CHUNK for w in writes)
    commit = dev.sent[-1]
    assert isinstance(commit, pg.TableCommitReq)
    assert (commit.length, commit.crc32, commit.force) == (581, tables.decode(data).crc32, 0)
    assert tables.pull(dev) == data


def test_push_refuses_other_uid_and_radio_before_sending() -> None:
    data = tables.build(UID, _curve(), created_unix=0)
    other = bytes(12)
    dev = FakeStation()
    with pytest.raises(TableError, match=f"for station {UID.hex()}, this station is {other.hex()}.*--force"):
        tables.push(dev, data, uid=other)
    with pytest.raises(TableError, match="channel 2 PRF 64 preamble 128.*channel 5.*--force"):
        tables.push(dev, data, uid=UID, radio=(5, 64, 128))
    assert dev.sent == []
    tables.push(dev, data, uid=other, radio=(5, 64, 128), force=True)
    assert dev.sent[-1].force == 1 and dev.table == data


def test_push_never_sends_an_invalid_table() -> None:
    data = tables.build(UID, _curve(), created_unix=0)
    t = tables.decode(data)
    bad = tables.seal(dataclasses.replace(t, curve_dbm=(t.curve_dbm[1],) + t.curve_dbm[1:]))
    dev = FakeStation()
    with pytest.raises(TableError, match="table field curve_dbm: point 1 .* not strictly increasing"):
        tables.push(dev, bad, uid=UID, force=True)
    assert dev.sent == []


def test_station_refusal_names_the_field() -> None:
    data = tables.build(UID, _curve(), created_unix=0)
    dev = FakeStation()
    dev.commit_error = tables.FIELD_NAMES.index("map_real_dbm")
    with pytest.raises(TableError, match="station refused the table: field map_real_dbm"):
        tables.push(dev, data, uid=UID)
    dev.commit_error = tables.FIELD_NAMES.index("uid")
    with pytest.raises(TableError, match="field uid .*--force"):
        tables.push(dev, data, uid=UID)
    dev.commit_error = tables.DETAIL_REQUEST | 1
    with pytest.raises(TableError, match="commit crc32"):
        tables.push(dev, data, uid=UID)


def test_lost_commit_answer_is_checked_by_info() -> None:
    data = tables.build(UID, _curve(), created_unix=0)
    dev = FakeStation()
    dev.commit_timeout = True
    r = tables.push(dev, data, uid=UID)   # the station has it: info shows its CRC
    assert r.slot == 0 and isinstance(dev.sent[-1], pg.TableInfoReq)
    dev2 = FakeStation()
    dev2.commit_timeout = True
    other = tables.build(UID, _curve(9), created_unix=0)
    dev2.table = None

    def lost(msg: Any, /, **kw: Any) -> Any:
        if isinstance(msg, pg.TableCommitReq):
            raise DeviceTimeout("fake: no answer")   # and nothing was written
        return FakeStation.request(dev2, msg, **kw)

    dev2.request = lost  # type: ignore[method-assign]
    with pytest.raises(DeviceTimeout):
        tables.push(dev2, other, uid=UID)


# --- build from a session -----------------------------------------------------------------------

def _sweep_session(path: Path, uid_hex: str) -> tuple[np.ndarray, np.ndarray]:
    """A P1/P2/P3 power sweep seen by station 2 from station 1, in closed form: linear clocks,
    P2's RX timestamp late by a known E(real power), the level estimate right below -85 dBm and
    compressed above, P2 stepped down by the 7 coarse gains (3 dB each). Returns the true real
    power of P2 (dBm) and E(P2) - E(P1) (s) per step."""
    from uwbcal.sessions.store import Session

    rng = np.random.default_rng(3)
    u = dw1000.TIME_UNIT_S
    steps, per, eps, p13 = 7, 30, 7e-6, -78.0
    real = p13 - 3.0 * np.arange(steps)

    def e_of(p: float) -> float:
        return 1e-12 * (-6.0 * (p + 92.0) - 0.15 * (p + 92.0) ** 2)

    def measured(p: float) -> float:
        return p if p < -85.0 else -85.0 + 0.5 * (p + 85.0)

    names = ("seq", "step", "tx_station", "rx_station", "gain13", "gain2", "tx1", "tx2", "tx3",
             "rx1", "rx2", "rx3", "cir_pwr1", "rxpacc1", "cir_pwr2", "rxpacc2", "cir_pwr3", "rxpacc3")
    rows: dict[str, list[int]] = {k: [] for k in names}
    seq = 0
    for k in range(steps):
        for _ in range(per):
            p = (p13, float(real[k]), p13)
            for i in range(3):
                tx = round((0.01 * seq + 1e-3 + 2e-3 * i) / u / 512) * 512
                rx = ((1 + eps) * tx * u + 0.5 + e_of(p[i])) / u + rng.normal(0, 0.3)
                rows[f"tx{i + 1}"].append(tx % dw1000.TIMESTAMP_MOD)
                rows[f"rx{i + 1}"].append(round(rx) % dw1000.TIMESTAMP_MOD)
                rows[f"cir_pwr{i + 1}"].append(round(float(dw1000.cir_pwr_for_level(measured(p[i]), 1000))))
                rows[f"rxpacc{i + 1}"].append(1000)
            for name, v in (("seq", seq), ("step", k), ("tx_station", 1), ("rx_station", 2),
                            ("gain13", dw1000.gain_octet(0, 0)), ("gain2", dw1000.gain_octet(k, 0))):
                rows[name].append(v)
            seq += 1
    s = Session.create(path, {"kind": "simulated", "experiment": "power", "station_uids": {"2": uid_hex},
                              "radio": {"channel": 2, "prf_mhz": 64, "preamble_length": 128,
                                        "data_rate_kbps": 6810}})
    s.append("triplets", {k: np.asarray(v) for k, v in rows.items()})
    s.close()
    return real, np.array([e_of(float(r)) - e_of(p13) for r in real])


def test_build_from_session(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    real, rel_err = _sweep_session(tmp_path / "s.db", "a0:a1:a2:a3:a4:a5:a6:a7:a8:a9:aa:ab")
    out = tmp_path / "t.json"
    assert cli.main(["table", "build", str(tmp_path / "s.db"), "--out", str(out), "--z-m", "0.3"]) == 0
    assert "station 2" in capsys.readouterr().out
    t = tables.check(tables.load(out), bytes.fromhex("a0a1a2a3a4a5a6a7a8a9aaab"))
    assert (t.channel, t.prf_mhz, t.preamble_len, t.data_rate) == (2, 64, 128, 2)
    assert t.z_ps == pytest.approx(0.5 * 0.3 / dw1000.C_LIGHT * 1e12, rel=1e-6)
    assert t.n_curve == 7
    # the curve is E(P2) - E(P1) at each step's measured level; the map gives the real power back
    got = np.array(t.curve_ps[:7])
    order = np.argsort(real)   # the table is sorted by level
    assert np.allclose(np.array(t.map_real_dbm[:7]), real[order], atol=0.3)
    assert np.allclose(got, (rel_err * 1e12)[order], atol=2.0), got
    # no UID for the station: one-line error
    assert cli.main(["table", "build", str(tmp_path / "s.db"), "--out", str(out), "--station", "5"]) == 6
    assert "station 5" in capsys.readouterr().err
