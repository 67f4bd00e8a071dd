"""Where the emulated SPI1 bytes go: the DW1000 register model of uwbcal.medium.registers.

- :class:`TunnelRadio`: the medium's model of this station, through the same tunnel a native
  station uses (protocol/messages/tunnel.toml). Time is kept in lock-step: before every SPI
  transaction and reset, and whenever the machine asks (:meth:`TunnelRadio.sync`), the
  medium is brought to the CPU's time with a ``tun_wait`` that ignores the IRQ, so the
  register model sees each access at the emulated instant it happens (to 1 us, the tunnel's
  unit). While the CPU sleeps (WFI) :meth:`TunnelRadio.wait` lets the medium run to the next
  timer event or the DW1000 IRQ, whichever is first, and returns early on host-link input.
- :class:`LocalRadio`: a register model in this process with no air around it (no medium):
  registers answer, nothing is ever received, a TX never ends. For boot, link and flash
  tests.
"""

from __future__ import annotations

import select
from collections.abc import Callable
from typing import Any, Protocol

from uwbcal.dw1000 import TIME_UNIT_S
from uwbcal.medium import wire
from uwbcal.medium.airtime import FrameFormat
from uwbcal.medium.client import TunnelClient
from uwbcal.medium.registers import Dw1000Model


class Radio(Protocol):
    """The DW1000 as the SPI1 model and the station loop see it."""

    irq: bool

    def spi_write(self, hdr: bytes, data: bytes) -> None:
        """An SPI write transaction (header, then data)."""

    def spi_read(self, hdr: bytes, n: int) -> bytes:
        """An SPI read transaction: the n bytes the chip clocks out after the header."""

    def reset(self) -> None:
        """RSTn was pulsed: every register to its power-on value."""

    def sync(self) -> None:
        """Bring the chip to the CPU's time and refresh :attr:`irq`."""

    def sleep(self, deadline_us: int, idle: bool, wake_fd: int | None) -> int:
        """The CPU sleeps (WFI): until the IRQ, ``deadline_us`` (CPU time) or input on
        ``wake_fd``; returns the time reached, us."""


class TunnelRadio(TunnelClient):
    """The medium's DW1000 model of station ``station_id``."""

    def __init__(self, path: str, station_id: int, uid: bytes, now_us: Callable[[], int]) -> None:
        super().__init__(path, station_id, uid)
        self.cpu_us = now_us
        self.med_us = self.now_us
        self.irq = False
        self.round_trips = 1
        self.waits = 0

    def _wait_to(self, deadline_us: int, mode: int) -> None:
        now, irq = TunnelClient.wait(self, deadline_us, mode)
        self.round_trips += 1
        self.med_us, self.irq = now, irq

    def sync(self) -> None:
        """tun_wait(CPU time, ignore IRQ): the medium reaches the CPU's time; irq refreshed."""
        self._wait_to(max(self.cpu_us(), self.med_us), wire.MODE_IGNORE_IRQ)

    def spi_write(self, hdr: bytes, data: bytes) -> None:
        """Posted tun_spi_write at the CPU's time."""
        if self.cpu_us() > self.med_us:
            self.sync()
        self._send(wire.TUN_SPI_WRITE, bytes([len(hdr)]) + hdr + data)

    def spi_read(self, hdr: bytes, n: int) -> bytes:
        """tun_spi_read at the CPU's time."""
        if self.cpu_us() > self.med_us:
            self.sync()
        self.round_trips += 1
        return self._request(wire.TUN_SPI_READ, n.to_bytes(2, "little") + hdr)

    def reset(self) -> None:
        """tun_reset at the CPU's time."""
        if self.cpu_us() > self.med_us:
            self.sync()
        self.round_trips += 1
        TunnelClient.reset(self)

    def wait(self, deadline_us: int, mode: int = 0, wake_fd: int | None = None) -> tuple[int, bool]:  # type: ignore[override]
        """tun_wait; with ``wake_fd`` input there cancels it (the medium answers at once)."""
        if wake_fd is None:
            return TunnelClient.wait(self, deadline_us, mode)
        self.send_wait(deadline_us, mode)
        while True:
            watch: list[Any] = [self.sock, wake_fd]
            r, _, _ = select.select(watch, [], [], 1.0)
            if self.sock in r:
                break
            if wake_fd in r:
                self.cancel()
                break
        return self.wait_answer()

    def sleep(self, deadline_us: int, idle: bool, wake_fd: int | None) -> int:
        """The CPU sleeps (WFI) until the IRQ, the deadline or host input; returns the time."""
        self.waits += 1
        mode = (wire.MODE_IDLE if idle else 0) | (wire.MODE_IGNORE_IRQ if self.irq else 0)
        now, irq = self.wait(max(deadline_us, self.med_us), mode, wake_fd)
        self.round_trips += 1
        self.med_us, self.irq = now, irq
        return now


class LocalRadio:
    """A DW1000 register model with no medium: the chip answers, the air is empty."""

    def __init__(self, now_us: Callable[[], int]) -> None:
        self.cpu_us = now_us
        self.model = Dw1000Model(host=self)
        self.irq = False
        self.round_trips = 0
        self.waits = 0

    # ChipHost
    def sys_time_units(self) -> float:
        """The chip's clock: the CPU's time (an ideal crystal), device units."""
        return self.cpu_us() * 1e-6 / TIME_UNIT_S

    def start_tx(self, dx_units: int | None, tx_antd: int, fmt: FrameFormat) -> int | None:
        """A frame into empty air: it is stamped but never ends (no TX done)."""
        return (dx_units if dx_units is not None else int(self.sys_time_units())) + tx_antd

    def radio_off(self) -> None:
        """Nothing to cancel."""

    def rx_enable(self, at_units: float | None) -> None:
        """Nothing will arrive."""

    def temperature_c(self) -> float:
        """23 degC."""
        return 23.0

    # Radio
    def spi_write(self, hdr: bytes, data: bytes) -> None:
        """Apply a write to the model."""
        self.model.spi_write(hdr, data)
        self.irq = self.model.irq

    def spi_read(self, hdr: bytes, n: int) -> bytes:
        """Read from the model."""
        return self.model.spi_read(hdr, n)

    def reset(self) -> None:
        """Power-on values."""
        self.model.reset()
        self.irq = False

    def sync(self) -> None:
        """The model's time is the CPU's: nothing to do."""
        self.irq = self.model.irq

    def sleep(self, deadline_us: int, idle: bool, wake_fd: int | None) -> int:
        """Sleep until the deadline or host input (real time is not waited for)."""
        self.waits += 1
        if wake_fd is not None and not idle:
            return deadline_us
        if wake_fd is not None:
            r, _, _ = select.select([wake_fd], [], [], 0.05)
            if r:
                return self.cpu_us()
        return deadline_us
