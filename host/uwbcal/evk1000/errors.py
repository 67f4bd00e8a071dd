"""Errors of the emulated EVK1000: every one names what went wrong, where (PC) and on what."""

from __future__ import annotations

from uwbcal.errors import UwbcalError


class EmulatorError(UwbcalError):
    """The emulated image did something a real STM32F105 would fault on (or the emulator
    cannot model): an unmapped or unaligned access, an unexpected exception, a stack
    overflow. The message names the PC and the address."""

    exit_code = 9


class BusError(Exception):
    """Raised by a peripheral model for an access it does not implement; the machine turns
    it into an :class:`EmulatorError` naming the PC and the address."""


class PowerCut(Exception):
    """The power-cut switch of the flash model fired: the emulated MCU loses power now."""
