"""One definition per fact: `make gen-check` (tools/gen_protocol.py --check) fails when a
hand-written copy of a protocol, table or chip fact appears (tools/protogen/copies.py), and the
tree holds none. Also the chip facts against the DW1000 User Manual's own numbers."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_protocol_gen import GEN, ROOT  # the generator, loaded once (tools/ is then on sys.path)
from uwbcal import dw1000


def find_copies(root: Path, *args: object) -> list[str]:
    """tools/protogen/copies.find_copies (importable once GEN has put tools/ on sys.path)."""
    from protogen.copies import find_copies as scan

    return scan(root, *args)  # type: ignore[arg-type]

COPIES = [
    ("py", "ERR_BAD_CRC: Final = 2", "ERR_BAD_CRC"),
    ("py", "TUN_WAIT: Final = 0x43", "TUN_WAIT"),
    ("py", "MODE_SNAPSHOT = 0x04", "MODE_SNAPSHOT"),
    ("c", "#define TABLE_SLOT_TORN 2", "TABLE_SLOT_TORN"),
    ("c", "    TABLE_SLOT_CORRUPT = 3,  /* committed but fails a check */", "TABLE_SLOT_CORRUPT"),
    ("c", "#define CALTABLE_A_MAX 130.0f", "A_MAX"),
    ("py", "DBM_MIN: Final = -120.0", "DBM_MIN"),
    ("c", "#define CALTABLE_READ_MAX 500u", "READ_MAX"),
    ("py", "SAR_DEGC_PER_LSB = 1.14", "sar_temp_degc_per_lsb"),
    ("py", "TTCKI = {16: 0x01F00000, 64: 0x01FC0000}", "rx_ttcki_prf16"),
    ("c", "#define C_LIGHT 299792458.0", "c_light"),
    ("py", "_PREAMBLES = (64, 128, 256, 512, 1024, 1536, 2048, 4096)", "preamble_lengths"),
    ("c", "static const uint16_t ok[] = { 64, 128, 256, 512, 1024, 1536, 2048, 4096 };", "preamble_lengths"),
    ("py", 'SLOT_STATES = {0: "empty", 1: "valid", 2: "torn", 3: "corrupt"}', "table_slot_state"),
    ("py", 'WAIT_REQ = struct.Struct("<QB")', "tun_wait"),
    ("py", 'SNAP_BLOCK = struct.Struct("<BHB")', "tun_snap_block"),
    ("c", "#define DW_PMSC_SOFTRESET 0x03", "PMSC_SOFTRESET"),
    ("c", "#define TUN_REG_SYS_TIME 0x06u", "SYS_TIME"),
    ("py", "DEV_ID: Final = 0xDECA0130", "dev_id_value"),
]
NOT_COPIES = [
    ("py", "x = 32"),
    ("py", "timeout = 2"),
    ("c", "#define LINK_RETRIES 3"),
    ("c", "static int n = 5000;"),
    ("py", "SCALE = 1.14  # not-a-copy: a plotting margin that happens to equal the SAR slope"),
    ("py", "# ERR_BAD_CRC = 2 in a comment"),
]


def _scan(tmp_path: Path, ext: str, line: str) -> list[str]:
    f = tmp_path / "host" / "uwbcal" / f"copy.{ext}"
    f.parent.mkdir(parents=True, exist_ok=True)
    f.write_text(line + "\n")
    return find_copies(tmp_path, GEN.load(), GEN.load_chip(), [f])


def test_the_tree_holds_no_copy() -> None:
    assert find_copies(ROOT, GEN.load(), GEN.load_chip()) == []


@pytest.mark.parametrize("ext, line, what", COPIES)
def test_a_copy_is_found(tmp_path: Path, ext: str, line: str, what: str) -> None:
    found = _scan(tmp_path, ext, line)
    assert found and any(what in f for f in found), found


@pytest.mark.parametrize("ext, line", NOT_COPIES)
def test_no_false_alarm(tmp_path: Path, ext: str, line: str) -> None:
    assert _scan(tmp_path, ext, line) == []


def test_a_copy_fails_gen_check(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                capsys: pytest.CaptureFixture[str]) -> None:
    """The build step itself: gen --check exits 1 naming the file, and 0 once it is gone."""
    f = tmp_path / "firmware" / "core" / "copy.h"
    f.parent.mkdir(parents=True)
    f.write_text("#define TUN_WAIT_MODE_IDLE 0x01u\n")
    monkeypatch.setattr(GEN, "ROOT", tmp_path)
    assert GEN.main(["--check"]) == 1
    assert "firmware/core/copy.h:1" in capsys.readouterr().err
    f.unlink()
    assert GEN.main(["--check"]) == 0


def test_chip_facts_against_the_user_manual() -> None:
    """Values as the DW1000 User Manual states them (not read from the shared source)."""
    # 6.4 Measuring IC temperature and voltage: T = (SAR_LTEMP - Vtemp@23C) x 1.14 + 23.
    assert dw1000.SAR_DEGC_PER_LSB == 1.14 and dw1000.SAR_REF_DEGC == 23.0
    # 7.2.21 RX_TTCKI: 0x01F00000 at PRF 16, 0x01FC0000 at PRF 64.
    assert dw1000.RX_TTCKI_BY_PRF == {16: 0x01F00000, 64: 0x01FC0000}
    # System time: 40 bits at 128 x 499.2 MHz, about 15.65 ps a unit.
    assert dw1000.TIMESTAMP_MOD == 2**40 and abs(dw1000.TIME_UNIT_S - 15.65e-12) < 0.01e-12


def test_medium_temperature_reads_as_the_manual_says() -> None:
    """The medium's SAR latch inverts the manual's formula: 88 degC, Vtemp@23 = 0x80 -> 0x80 + 57
    (65 / 1.14 = 57.0; the old slope 1.13 gave 57.5 -> 58)."""
    from uwbcal.medium.registers import OTP_VTEMP_ADDR, TC_SARL_OFF, TX_CAL, Dw1000Model

    class Host:
        def temperature_c(self) -> float:
            return 88.0

    m = Dw1000Model(host=Host())  # type: ignore[arg-type]  # only the temperature is asked for
    m.otp[OTP_VTEMP_ADDR] = 0x8000
    m._latch_sar()
    assert m.get(TX_CAL, TC_SARL_OFF + 1, 1) == 0x80 + 57


CONST = '[[constant]]\nname = "{name}"\ntype = "{type}"\nvalue = {value}\nunit = ""\ndoc = ""\n'


@pytest.mark.parametrize(
    "extra, why",
    [
        (CONST.format(name="k", type="u8", value=300), "does not fit u8"),
        (CONST.format(name="k", type="u8", value=1) * 2, "defined twice"),
        (CONST.format(name="k", type="nosuch", value=1), "type must be one of"),
        ('[[enum]]\nname = "m"\nbits = true\ndoc = ""\nvalues = [{ name = "a", value = 3, doc = "" }]\n',
         "one bit per value"),
        ('[[message]]\nname = "a"\ntype = 0x01\ndoc = ""\n'
         'request = [{ name = "x", type = "f32[nosuch]", unit = "", doc = "" }]\n',
         "not an integer constant"),
    ],
)
def test_bad_constants_are_refused(tmp_path: Path, extra: str, why: str) -> None:
    from test_protocol_gen import make_proto

    with pytest.raises(GEN.ProtocolDefError, match=why):
        GEN.load(make_proto(tmp_path, extra))


def test_array_length_named_by_a_constant(tmp_path: Path) -> None:
    from test_protocol_gen import make_proto

    extra = CONST.format(name="n_pts", type="u8", value=7) + (
        '[[struct]]\nname = "s"\ndoc = ""\n'
        'fields = [{ name = "x", type = "f32[n_pts]", unit = "", doc = "" }]\n')
    p = GEN.load(make_proto(tmp_path, extra))
    assert p.structs["s"].size == 28 and p.constants["n_pts"].value == 7
