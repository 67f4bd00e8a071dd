"""The USB link of the emulated EVK1000: the OTG FS model (otgfs.py) on the machine that runs
the shipped image byte for byte (machine.py, issue 10), and the USB host (usbhost.py) that
enumerates it.

    machine = Machine(flash, uid=..., radio=..., link_sink=...)   # the image in flash
    otg, host = attach_usb(machine)
    host.enumerate(); host.cdc_open()                                # as Linux does

:class:`MachineRunner` is the host's DeviceRunner: it runs the CPU for the asked microseconds
of emulated time, and when the image sleeps in WFI with nothing pending, lets the time pass up
to the next timer event. Only what this module needs of the machine is assumed (the
:class:`EmulatedMcu` protocol below).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from uwbcal.evk1000.otgfs import OtgFs
from uwbcal.evk1000.usbhost import UsbHost


class EmulatedMcu(Protocol):
    """The part of the emulated STM32F105 (machine.Machine) the USB link uses."""

    nvic: Any
    cycles: int

    @property
    def sysclk_hz(self) -> int: ...
    def attach(self, p: Any) -> None: ...
    def run(self, budget_cycles: int) -> str: ...
    def time_us(self) -> int: ...
    def cycles_at_us(self, t_us: int) -> int: ...
    def advance_to_us(self, t_us: int) -> None: ...
    def next_event_cycle(self) -> int | None: ...


class MachineRunner:
    """Runs the emulated MCU for some microseconds of its own time (usbhost.DeviceRunner, and
    the device side of usbbridge.UsbPtyBridge: the NVIC model takes the USB interrupt by
    itself, so there is no interrupt to service and no wait hook)."""

    def __init__(self, machine: EmulatedMcu) -> None:
        self.m = machine
        self.wait_hook: Callable[[], None] | None = None

    @property
    def time_us(self) -> int:
        return self.m.time_us()

    def service_irq(self) -> None:
        """Nothing: the machine's NVIC model takes the interrupt when the CPU runs."""

    def should_exit(self) -> bool:
        return False

    def set_link_fd(self, fd: int) -> None:
        """Nothing: the machine has no idle wait to cut short."""

    def run_us(self, us: int) -> None:
        m = self.m
        end = m.time_us() + us
        for _ in range(1_000_000):  # bounded: every pass runs code or moves time forward
            now = m.time_us()
            if now >= end:
                return
            if m.run(max(m.cycles_at_us(end) - m.cycles, 1)) == "wfi":
                ev = m.next_event_cycle()
                wake = end if ev is None else now + max(1, (ev - m.cycles) * 1_000_000 // m.sysclk_hz)
                m.advance_to_us(min(end, wake))


def attach_usb(machine: EmulatedMcu) -> tuple[OtgFs, UsbHost]:
    """Put the OTG FS model on the machine's bus (0x50000000, NVIC line 67) and a USB host on
    its port; returns both."""
    otg = OtgFs(nvic=machine.nvic)
    machine.attach(otg)
    return otg, UsbHost(otg, MachineRunner(machine))
