"""An emulated EVK1000 (STM32F105RC + DW1000) that runs the shipped image byte for byte.

The CPU is Unicorn's Cortex-M3 (``UC_MODE_THUMB | UC_MODE_MCLASS``); everything Unicorn does
not have is modelled here, one small module per block, each naming the RM0008 / PM0056
section it follows:

=============  =====================================================================
machine.py     the CPU loop, memory map, exception entry/return, time, faults, stack
nvic.py        NVIC and SCB (PM0056 4.2, 4.3): pending/active bits, priorities
systick.py     SysTick (PM0056 4.4), counting emulated cycles
rcc.py         RCC (RM0008 8.3): ready bits, HSE failure switch, the clock tree
fpec.py        embedded flash and its interface (RM0008 3.3.3, PM0075), file backed
gpio.py        GPIO ports and AFIO (RM0008 9.2, 9.4)
exti.py        EXTI (RM0008 10.3)
usart.py       USART1 (RM0008 27.6), bytes to and from a host link
uid.py         the 96-bit unique ID and the flash size register (RM0008 30.1, 30.2)
spi.py         SPI1 (RM0008 25.5) clocking bytes into the DW1000 register model
radio.py       where the SPI bytes go: the medium's DW1000 register model (tunnel) or
               a local one (no medium)
image.py       symbols of the ELF beside the image (names in messages, stack floor)
errors.py      EmulatorError (one line: access, address, PC), BusError, PowerCut
station.py     one emulated station process: a pty host link, the medium tunnel
gdbstub.py     a GDB remote-serial-protocol stub (load, memory, reset, detach)
otgfs.py       USB OTG FS core in device mode (RM0008 28), the EVK1000's PC link
usbhost.py     a USB host that enumerates it as Linux does; descriptor checks (CDC 1.2)
usbbridge.py   its bulk endpoints as a pty, like /dev/ttyACM0
usbmachine.py  the OTG FS model and a USB host on this machine
usbhosted.py   the USB driver built for the host (no CPU emulator), on the same model
usbstation.py  a simulated station whose link is that driver on the model
=============  =====================================================================

Peripheral interface (kept stable: other peripheral models, e.g. USB OTG FS, plug in here).
A peripheral is any object with

- ``name: str``, ``base: int`` (bus address), ``size: int`` (bytes of address space);
- ``read(offset: int, width: int) -> int`` and ``write(offset: int, width: int, value: int)
  -> None``, ``offset`` from ``base``, ``width`` 1, 2 or 4 bytes;
- optionally ``tick(cycles: int) -> None``: called after each slice of execution with the
  CPU cycles (the emulated time base) that slice took;
- optionally ``next_event_cycle() -> int | None``: the cycle count at which the peripheral
  next needs the CPU (a slice ends there, a WFI sleeps no longer);
- optionally ``reset() -> None``: a system reset (AIRCR.SYSRESETREQ or power-on).

It is attached with :meth:`uwbcal.evk1000.machine.Machine.attach`. It raises an interrupt
with ``machine.nvic.set_pending(irqn)`` (``irqn`` as in RM0008 table 62, e.g. 37 for
USART1) and withdraws a level interrupt with ``machine.nvic.clear_pending(irqn)``; the
current time is ``machine.cycles`` (CPU cycles since power-on) or ``machine.time_us()``.
An access to an offset a peripheral does not implement should raise
:class:`uwbcal.evk1000.errors.BusError` (the machine reports it with the PC), never
return a silent zero.
"""

from __future__ import annotations

from typing import Protocol


class Peripheral(Protocol):
    """A memory-mapped peripheral model (see the module docstring)."""

    name: str
    base: int
    size: int

    def read(self, offset: int, width: int) -> int:
        """The value read at ``base + offset`` with an access of ``width`` bytes."""

    def write(self, offset: int, width: int, value: int) -> None:
        """A write of ``width`` bytes at ``base + offset``."""
