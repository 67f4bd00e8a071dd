"""The generator (tools/gen_protocol.py): checked-in output up to date and deterministic,
definitions validated, and the generated Python codecs round-trip (hypothesis, derandomized)."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from uwbcal.errors import ProtocolError
from uwbcal.link import proto_gen as pg

ROOT = Path(__file__).resolve().parents[2]


def load_gen() -> ModuleType:
    spec = importlib.util.spec_from_file_location("gen_protocol", ROOT / "tools" / "gen_protocol.py")
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    sys.modules["gen_protocol"] = mod
    spec.loader.exec_module(mod)
    return mod


GEN = load_gen()


def test_checked_in_output_is_current() -> None:
    r = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "gen_protocol.py"), "--check"], capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr


def test_output_is_deterministic() -> None:
    assert GEN.outputs() == GEN.outputs()


def test_python_constants_match_definition() -> None:
    p = GEN.load()
    assert pg.PROTOCOL_VERSION == p.version and pg.MAX_PAYLOAD == p.max_payload
    assert {m.name: m.type for m in p.messages} == {n: t for t, n in pg.MESSAGE_NAMES.items()}
    assert {k: c for k, (c, _) in p.errors.items()} == {n: c for c, n in pg.ERROR_NAMES.items()}
    assert pg.HEADER.size == pg.HEADER_SIZE == 5


def make_proto(tmp_path: Path, messages: str) -> Path:
    d = tmp_path / "protocol"
    (d / "messages").mkdir(parents=True)
    shutil.copy(ROOT / "protocol" / "protocol.toml", d / "protocol.toml")
    (d / "messages" / "core.toml").write_text(
        '[[message]]\nname = "error"\ntype = 0x7F\ndoc = ""\nrequest = []\nresponse = []\n' + messages
    )
    return d


def msg(name: str = "a", type_: str = "0x01", *fields: str) -> str:
    """One [[message]] table with the given request fields (TOML inline tables)."""
    return f'[[message]]\nname = "{name}"\ntype = {type_}\ndoc = ""\nrequest = [{", ".join(fields)}]\n'


def fld(name: str, type_: str) -> str:
    return f'{{ name = "{name}", type = "{type_}", unit = "", doc = "" }}'


@pytest.mark.parametrize(
    "bad, why",
    [
        (msg("a") + msg("b"), "already used"),
        (msg("a", "0x60"), "no declared type range"),
        (msg("a", "0x01", fld("t", "tail"), fld("x", "u8")), "tail must be the last"),
        (msg("a", "0x01", fld("x", "bytes[600]")), "exceeds max_payload"),
        (msg("a", "0x01", fld("x", "nosuch")), "unknown type"),
        (msg("a", "0x01", fld("x", "u8"), fld("x", "u8")), "duplicate field"),
        (msg("Bad-Name"), "bad name"),
        (msg("a", "0x20", fld("x", "u8")), "streamed message"),
        (msg("a", "0x01", '{ name = "x", type = "u8", doc = "" }'), "unit and a doc"),
        (msg("a", "0x01", fld("x", "u8[0]")), "array length"),
        (msg("a", "0x01", fld("x_len", "u8"), fld("x", "tail")), "collides"),
    ],
)
def test_invalid_definitions_rejected(tmp_path: Path, bad: str, why: str) -> None:
    with pytest.raises(GEN.ProtocolDefError, match=why):
        GEN.load(make_proto(tmp_path, bad))


def test_valid_minimal_definition(tmp_path: Path) -> None:
    p = GEN.load(make_proto(tmp_path, msg("a")))
    assert [m.name for m in p.messages] == ["a", "error"]


u16 = st.integers(0, 0xFFFF)
i32 = st.integers(-(2**31), 2**31 - 1)
u32 = st.integers(0, 2**32 - 1)
u64 = st.integers(0, 2**64 - 1)
rxq = st.builds(
    pg.RxQuality,
    cir_pwr=u16,
    rxpacc=u16,
    rxpacc_nosat=u16,
    fp_ampl1=u16,
    fp_ampl2=u16,
    fp_ampl3=u16,
    std_noise=u16,
    fp_index=u16,
    car_int=i32,
    ttcko=i32,
    ttcki=u32,
)
trip = st.builds(
    pg.TripletRecord,
    seq=u32,
    step=u16,
    tx_station=u16,
    gain13=st.integers(0, 255),
    gain2=st.integers(0, 255),
    tx=st.tuples(u64, u64, u64),
    rx=st.tuples(u64, u64, u64),
    q=st.tuples(rxq, rxq, rxq),
    temp_cc=st.integers(-(2**15), 2**15 - 1),
)


@settings(derandomize=True, max_examples=200)
@given(recs=st.lists(trip, min_size=0, max_size=pg.TripletsResp.TAIL_MAX), first=u32)
def test_triplets_round_trip(recs: list[pg.TripletRecord], first: int) -> None:
    m = pg.TripletsResp(first_index=first, records=tuple(recs))
    data = m.encode()
    assert len(data) == 4 + len(recs) * pg.TripletRecord.WIRE_SIZE <= pg.MAX_PAYLOAD
    assert pg.TripletsResp.decode(data) == m
    arr = pg.records_array(pg.TripletRecord, data[4:])
    assert arr.shape == (len(recs),)
    assert list(arr["seq"]) == [r.seq for r in recs]
    assert [tuple(int(x) for x in row) for row in arr["q"]["car_int"]] == [
        tuple(q.car_int for q in r.q) for r in recs
    ]


@settings(derandomize=True, max_examples=200)
@given(data=st.binary(max_size=pg.MAX_PAYLOAD))
def test_ping_round_trip_and_lengths(data: bytes) -> None:
    assert pg.PingReq.decode(pg.PingReq(data=data).encode()).data == data


def test_length_errors() -> None:
    with pytest.raises(ProtocolError, match="get_info response"):
        pg.GetInfoResp.decode(bytes(10))
    with pytest.raises(ProtocolError):
        pg.TripletsResp.decode(bytes(4 + pg.TripletRecord.WIRE_SIZE - 1))
    with pytest.raises(ValueError):
        pg.PingReq(data=bytes(pg.MAX_PAYLOAD + 1)).encode()
    with pytest.raises(ValueError, match="uid"):
        pg.GetInfoResp(uid=bytes(13)).encode()
    with pytest.raises(ValueError, match="get_info"):
        pg.GetInfoResp(fw_major=256).encode()
    with pytest.raises(ValueError, match="rx_quality"):
        pg.RxQuality(car_int=2**31).encode()
    with pytest.raises(ValueError, match="board"):
        pg.GetInfoResp(board="x" * 17).encode()


def test_str_fields_and_numpy_dtype() -> None:
    r = pg.GetInfoResp.decode(pg.GetInfoResp(board="native", git_hash="abc").encode())
    assert (r.board, r.git_hash) == ("native", "abc")
    dt = pg.numpy_dtype(pg.RangeRecord)
    assert dt.itemsize == pg.RangeRecord.WIRE_SIZE
    assert np.dtype(dt["t"]).shape == (6,)
