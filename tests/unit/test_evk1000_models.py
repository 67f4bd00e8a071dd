"""Peripheral models of the emulated EVK1000 (uwbcal.evk1000) against RM0008 / PM0056 /
PM0075, each on its own, and the machine's fault reports on tiny hand-made images."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from uwbcal.evk1000.errors import BusError, EmulatorError, PowerCut
from uwbcal.evk1000.fpec import (
    CR_LOCK,
    CR_PER,
    CR_PG,
    CR_STRT,
    FLASH_BASE,
    KEY1,
    KEY2,
    SR_EOP,
    SR_PGERR,
    FlashFile,
    Fpec,
)
from uwbcal.evk1000.machine import Machine
from uwbcal.evk1000.nvic import Nvic
from uwbcal.evk1000.radio import LocalRadio
from uwbcal.evk1000.rcc import Rcc
from uwbcal.evk1000.systick import SysTick

TABLE = FLASH_BASE + 0x3F000


def _fpec(tmp_path: Path, cut_at: int | None = None) -> tuple[Fpec, FlashFile, list[float]]:
    flash = FlashFile(tmp_path / "f.flash")
    stalls: list[float] = []
    return Fpec(flash, lambda a, d: None, stalls.append, cut_at=cut_at), flash, stalls


def _unlock(f: Fpec) -> None:
    f.write(4, 4, KEY1)
    f.write(4, 4, KEY2)


def test_fpec_unlock_program_erase_and_file(tmp_path: Path) -> None:
    f, flash, stalls = _fpec(tmp_path)
    assert f.read(0x10, 4) & CR_LOCK
    with pytest.raises(BusError, match="without CR.PG"):
        f.program(TABLE, 2, 0x1234)
    _unlock(f)
    assert not f.read(0x10, 4) & CR_LOCK
    f.write(0x10, 4, CR_PG)
    f.program(TABLE, 2, 0x1234)
    assert f.read(0xC, 4) & SR_EOP and stalls == [pytest.approx(52.5e-6)]
    f.write(0xC, 4, SR_EOP)                                    # write 1 to clear
    f.program(TABLE, 2, 0xABCD)                                # not erased: refused
    assert f.read(0xC, 4) & SR_PGERR and flash.data[0x3F000:0x3F002] == b"\x34\x12"
    with pytest.raises(BusError, match="half-words only"):
        f.program(TABLE + 2, 4, 0)
    f.write(0x10, 4, CR_PER)
    f.write(0x14, 4, TABLE + 10)
    f.write(0x10, 4, CR_PER | CR_STRT)
    assert flash.data[0x3F000:0x3F800] == b"\xff" * 2048
    flash.close()
    assert (tmp_path / "f.flash").read_bytes()[0x3F000:0x3F002] == b"\xff\xff"   # in the file too


def test_fpec_wrong_key_locks_until_reset(tmp_path: Path) -> None:
    f, _flash, _ = _fpec(tmp_path)
    f.write(4, 4, KEY1)
    f.write(4, 4, 0x12345678)
    _unlock(f)
    assert f.read(0x10, 4) & CR_LOCK                           # PM0075: locked until reset
    f.reset()
    _unlock(f)
    assert not f.read(0x10, 4) & CR_LOCK


def test_fpec_power_cut_leaves_a_half_done_operation(tmp_path: Path) -> None:
    f, flash, _ = _fpec(tmp_path, cut_at=2)
    _unlock(f)
    f.write(0x10, 4, CR_PG)
    f.program(TABLE, 2, 0x0000)
    with pytest.raises(PowerCut, match="operation 2"):
        f.program(TABLE + 2, 2, 0x0000)
    assert flash.data[0x3F002:0x3F004] == b"\x00\xff"          # only the low byte got there


def test_systick_counts_cycles_and_pends_on_wrap() -> None:
    cycles = [0]
    pended: list[int] = []
    st = SysTick(lambda: cycles[0], lambda: pended.append(cycles[0]))
    st.write(4, 4, 999)                                        # RVR: 1000 cycles per period
    st.write(8, 4, 0)                                          # CVR cleared
    st.write(0, 4, 0b111)                                      # processor clock, TICKINT, ENABLE
    cycles[0] = 1
    assert st.read(8, 4) == 999
    cycles[0] = 500
    assert st.read(8, 4) == 500
    assert st.next_event_cycle() == 1000
    cycles[0] = 1000
    st.advance()
    assert pended == [1000] and st.read(0, 4) & (1 << 16)     # COUNTFLAG, cleared by the read
    assert not st.read(0, 4) & (1 << 16)


def test_nvic_priorities_and_masking() -> None:
    n = Nvic(lambda: None)
    n.write(0x400 - 0x100 + 23, 1, 0x20)                       # EXTI9_5 priority 2
    n.write(0x400 - 0x100 + 37, 1, 0x10)                       # USART1 priority 1
    n.write(0x100 - 0x100, 4, 1 << 23)                         # ISER0: EXTI9_5
    n.write(0x104 - 0x100, 4, 1 << (37 - 32))                  # ISER1: USART1
    n.set_pending(23)
    n.set_pending(37)
    assert n.next_exception(primask=True) is None
    assert n.next_exception(primask=False) == 16 + 37          # the more urgent one first
    n.activate(16 + 37)
    assert n.next_exception(primask=False) is None             # EXTI (prio 2) cannot preempt prio 1
    n.deactivate()
    assert n.next_exception(primask=False) == 16 + 23


def test_rcc_hse_failure_keeps_sysclk_on_hsi() -> None:
    for fails, hz in ((False, 72_000_000), (True, 8_000_000)):
        r = Rcc(hse_fails=fails)
        r.write(0, 4, r.read(0, 4) | (1 << 16))                                 # HSEON
        r.write(0x2C, 4, (4 << 0) | (2 << 4) | (8 << 8) | (1 << 16))            # as clock.c
        r.write(0, 4, r.read(0, 4) | (1 << 26))                                 # PLL2ON
        r.write(4, 4, (1 << 16) | (7 << 18))                                    # PLLSRC, x9
        r.write(0, 4, r.read(0, 4) | (1 << 24))                                 # PLLON
        r.write(4, 4, r.read(4, 4) | 2)                                         # SW = PLL
        assert r.sysclk_hz() == hz
        assert bool(r.read(0, 4) & (1 << 17)) is not fails


def _machine(tmp_path: Path, code: bytes) -> Machine:
    flash = FlashFile(tmp_path / "m.flash")
    flash.store(0, struct.pack("<II", 0x20001000, FLASH_BASE + 9) + code)
    holder: list[Machine] = []
    radio = LocalRadio(lambda: holder[0].time_us() if holder else 0)
    m = Machine(flash, uid=bytes(12), radio=radio, link_sink=lambda b: None)
    holder.append(m)
    return m


def test_unmapped_read_names_pc_and_address(tmp_path: Path) -> None:
    # 0x08000008: ldr r0, [pc, #4]; ldr r1, [r0]; b . ; nop; .word 0x60000000
    m = _machine(tmp_path, struct.pack("<HHHHI", 0x4801, 0x6801, 0xE7FE, 0xBF00, 0x60000000))
    with pytest.raises(EmulatorError, match=r"0x60000000.*PC 0x0800000a"):
        m.run(1000)


def test_unaligned_peripheral_read_is_an_error(tmp_path: Path) -> None:
    m = _machine(tmp_path, struct.pack("<HHHHI", 0x4801, 0x6801, 0xE7FE, 0xBF00, 0x40013801))
    with pytest.raises(EmulatorError, match=r"0x40013801: unaligned.*PC 0x0800000a"):
        m.run(1000)


def test_erased_flash_does_not_boot(tmp_path: Path) -> None:
    m = Machine(FlashFile(tmp_path / "e.flash"), uid=bytes(12), radio=LocalRadio(lambda: 0),
                link_sink=lambda b: None)
    with pytest.raises(EmulatorError, match="no bootable image"):
        m.run(10)


def test_usart_baud_timing_holds_txe_for_a_frame() -> None:
    from uwbcal.evk1000.usart import SR_TC, SR_TXE, Usart

    now = [0]
    out = bytearray()
    u = Usart(Nvic(lambda: None), out.extend, baud_timing=True, cycles=lambda: now[0])
    u.write(8, 4, 625)                                         # 72 MHz / 115200
    u.write(12, 4, (1 << 13) | (1 << 3) | (1 << 2))            # UE, TE, RE
    u.write(4, 4, 0x55)
    assert u.read(0, 4) & (SR_TXE | SR_TC) == SR_TXE           # in the shift register: DR free
    u.write(4, 4, 0x56)
    assert out == b"\x55\x56"
    now[0] = 6249
    assert not u.read(0, 4) & SR_TXE                           # 10 bits x 625 cycles not over
    now[0] = 6250
    assert u.read(0, 4) & (SR_TXE | SR_TC) == SR_TXE
    now[0] = 12500
    assert u.read(0, 4) & SR_TC
    u.feed(b"ab")
    assert u.read(4, 4) == ord("a")
    assert u.next_event_cycle() == now[0] + 6250               # the next byte one frame later


def test_scenario_board_key() -> None:
    from uwbcal.errors import ScenarioError
    from uwbcal.physics.scenario import parse_scenario

    text = '[[stations]]\nid = 1\nboard = "{}"\n[[stations]]\nid = 2\nposition_m = [2.0, 0.0, 0.0]\n'
    sc = parse_scenario(text.format("evk1000"))
    assert [s.board for s in sc.stations] == ["evk1000", "native"]
    with pytest.raises(ScenarioError, match="board: expected one of native, evk1000"):
        parse_scenario(text.format("evk2000"))


def test_gdb_stub_flash_packets(tmp_path: Path) -> None:
    """What GDB's `load` sends through the stub reaches the flash file (no gdb needed here)."""
    from uwbcal.evk1000.gdbstub import GdbStub, checksum

    m = Machine(FlashFile(tmp_path / "g.flash"), uid=bytes(12), radio=LocalRadio(lambda: 0),
                link_sink=lambda b: None)
    stub = GdbStub(m)
    try:
        assert b"qXfer:memory-map:read+" in stub.handle(b"qSupported:multiprocess+")[0]
        mm = stub.handle(b"qXfer:memory-map:read::0,fff")[0]
        assert mm.startswith(b"l") and b'type="flash" start="0x8000000"' in mm
        assert stub.handle(b"vFlashErase:08000000,800")[0] == b"OK"
        vector = struct.pack("<II", 0x20010000, 0x08000101)
        assert stub.handle(b"vFlashWrite:8000000:" + vector)[0] == b"OK"
        assert stub.handle(b"vFlashErase:08000001,800")[0] == b"E01"          # not a page
        assert stub.handle(b"m8000000,8")[0] == vector.hex().encode()
        assert stub.handle(b"M60000000,4:00000000")[0] == b"E01"              # not RAM
        assert stub.handle(b"qRcmd," + b"reset".hex().encode()) == (b"OK", None)
        assert m.pc == 0x08000100 and m.bootable
        assert stub.handle(b"D") == (b"OK", "detach")
        assert checksum(b"OK") == b"9a"
    finally:
        stub.close()
    assert (tmp_path / "g.flash").read_bytes()[:8] == vector


EXC_IMAGE = """
.syntax unified
.thumb
.word 0x20001000, reset, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, systick
.thumb_func
reset:
  ldr r0, =0xE000ED04      @ ICSR
  ldr r1, =0x04000000      @ PENDSTSET
  str r1, [r0]
loop:
  b loop
.thumb_func
systick:
  mrs r0, ipsr
  ldr r1, =0x20000000
  str r0, [r1]
  str sp, [r1, #4]
  bx lr
.ltorg
"""


def test_exception_entry_ipsr_and_return(tmp_path: Path) -> None:
    """SysTick pended by ICSR: the handler runs with IPSR 15 on an 8-word frame below the
    thread's SP, and EXC_RETURN brings the thread back with its SP."""
    import shutil
    import subprocess

    if shutil.which("arm-none-eabi-as") is None:
        pytest.skip("arm-none-eabi-as is missing (tools/bootstrap.sh installs it)")
    (tmp_path / "e.s").write_text(EXC_IMAGE)
    o, elf, binary = (str(tmp_path / n) for n in ("e.o", "e.elf", "e.bin"))
    subprocess.run(["arm-none-eabi-as", "-mcpu=cortex-m3", "-o", o, str(tmp_path / "e.s")], check=True)
    subprocess.run(["arm-none-eabi-ld", "-Ttext=0x08000000", "-o", elf, o], check=True)
    subprocess.run(["arm-none-eabi-objcopy", "-O", "binary", elf, binary], check=True)
    flash = FlashFile(tmp_path / "x.flash")
    flash.store(0, (tmp_path / "e.bin").read_bytes())
    m = Machine(flash, uid=bytes(12), radio=LocalRadio(lambda: 0), link_sink=lambda b: None)
    m.run(200)
    ipsr, handler_sp = struct.unpack("<II", bytes(m.uc.mem_read(0x20000000, 8)))
    assert ipsr == 15 and handler_sp == 0x20001000 - 32
    assert m.exceptions_taken == 1 and m.nvic.active == []
    from unicorn import arm_const as A

    assert m.uc.reg_read(A.UC_ARM_REG_SP) == 0x20001000
    assert m.uc.reg_read(A.UC_ARM_REG_IPSR) == 0
