"""Exceptions uwbcal raises. The CLI prints any UwbcalError as one line and exits non-zero."""


class UwbcalError(Exception):
    """Base of every error a user should see as one line, never as a traceback."""

    exit_code = 1


class LinkError(UwbcalError):
    """The host link failed: the port could not be opened, or it went away."""

    exit_code = 2


class DeviceTimeout(UwbcalError):
    """A station did not answer within its timeout after every retry."""

    exit_code = 3


class ProtocolError(UwbcalError):
    """A frame was malformed, of the wrong protocol version, or answered with ERROR."""

    exit_code = 4


class SessionError(UwbcalError):
    """A session file is missing, truncated, of an unknown schema, or inconsistent."""

    exit_code = 5


class TableError(UwbcalError):
    """A calibration table is malformed, out of bounds, or made for another station."""

    exit_code = 6


class ScenarioError(UwbcalError):
    """A scenario file is malformed or names an unknown effect or parameter."""

    exit_code = 7
