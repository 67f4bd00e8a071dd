"""Byte transports for the host link: anything pyserial's ``serial_for_url`` opens.

A real port (``/dev/ttyACM0``, ``COM3``), a simulated station's pty (``/dev/pts/7``),
``socket://host:port`` and ``loop://`` all go through the same code path. Every failure
becomes a :class:`~uwbcal.errors.LinkError` that names the port.
"""

from __future__ import annotations

import re

import serial

try:  # pyserial's POSIX ports call tcdrain/tcflush: a vanished port raises termios.error
    import termios

    _PORT_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError, termios.error)
except ImportError:  # pragma: no cover - Windows
    _PORT_ERRORS = (serial.SerialException, OSError)

from uwbcal.errors import LinkError

#: Baud rate for real UARTs; ignored by ptys, USB CDC, sockets and loop://.
DEFAULT_BAUDRATE = 115200


class Transport:
    """A byte stream to one station."""

    def __init__(self, port: str, baudrate: int = DEFAULT_BAUDRATE) -> None:
        self.port = port
        try:
            self._ser = serial.serial_for_url(
                port,
                baudrate=baudrate,
                timeout=0,
                write_timeout=2.0,
                exclusive=None if "://" in port else True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f"cannot open port {port}: {_reason(exc)}") from None
        self.reset_input()

    def reset_input(self) -> None:
        """Drop bytes received but not read (stale answers from an earlier session)."""
        try:
            self._ser.reset_input_buffer()
        except _PORT_ERRORS:
            pass

    def write(self, data: bytes) -> None:
        """Write every byte or raise LinkError."""
        try:
            self._ser.write(data)
            self._ser.flush()
        except _PORT_ERRORS as exc:
            raise LinkError(f"port {self.port}: write failed: {_reason(exc)}") from None

    def read(self, wait_s: float) -> bytes:
        """Bytes available now, waiting at most ``wait_s`` seconds for the first one."""
        try:
            self._ser.timeout = max(0.0, wait_s)
            first = self._ser.read(1)
            if not first:
                return b""
            self._ser.timeout = 0
            more = self._ser.in_waiting
            return bytes(first) + (bytes(self._ser.read(more)) if more else b"")
        except _PORT_ERRORS as exc:
            raise LinkError(f"port {self.port}: read failed: {_reason(exc)}") from None

    def close(self) -> None:
        try:
            self._ser.close()
        except _PORT_ERRORS:
            pass

    def __enter__(self) -> Transport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: What pyserial says when the other end of a port vanished, and what the user is told.
_GONE = ("returned no data", "the port went away (station unplugged, reset into another port, or stopped)")


def _reason(exc: BaseException) -> str:
    if type(exc).__name__ == "error" and exc.args and isinstance(exc.args[-1], str):
        return str(exc.args[-1])  # termios.error(errno, text)
    if _GONE[0] in str(exc):
        return _GONE[1]
    text = str(exc.strerror if isinstance(exc, OSError) and exc.strerror else exc).strip()
    m = re.search(r"\[Errno \d+\] ([^:']+)", text)
    if m:
        return m.group(1).strip()
    return text.splitlines()[0] if text else type(exc).__name__
