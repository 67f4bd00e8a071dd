"""The hand-written runtime of the generated protocol code (host/uwbcal/link/proto_gen.py).

tools/gen_protocol.py emits one frozen dataclass per struct and per message direction; what
they share (the base classes, field packing with clear errors, the numpy views of records)
lives here, once, and the generated module imports it (as Pigweed's generated code imports
pw_protobuf). Sizes are bytes; everything on the wire is little-endian with no padding.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any, ClassVar, Generic, Self, TypeVar

from uwbcal.errors import ProtocolError

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt


def arr(v: tuple[Any, ...], n: int, name: str) -> tuple[Any, ...]:
    """``v`` when it has exactly ``n`` elements (an array field), else ValueError naming the field."""
    if len(v) != n:
        raise ValueError(f"{name}: expected {n} values, got {len(v)}")
    return v


def fixed(b: bytes, n: int, name: str) -> bytes:
    """A bytes[n] field's value (shorter is zero-padded by struct), else ValueError."""
    if len(b) > n:
        raise ValueError(f"{name}: at most {n} bytes, got {len(b)}")
    return bytes(b)


def str_bytes(s: str, n: int, name: str) -> bytes:
    """A str[n] field's UTF-8 bytes, else ValueError when they do not fit."""
    e = s.encode("utf-8")
    if len(e) > n:
        raise ValueError(f"{name}: at most {n} UTF-8 bytes, got {len(e)}")
    return e


def pack(s: struct.Struct, name: str, *values: Any) -> bytes:
    """``s.pack(*values)``; a value out of its field's range is a ValueError naming ``name``."""
    try:
        return s.pack(*values)
    except struct.error as exc:
        raise ValueError(f"{name}: {exc}") from None


def unstr(b: bytes) -> str:
    """A str[n] field's text: up to the first NUL, invalid UTF-8 replaced."""
    return bytes(b).split(b"\0", 1)[0].decode("utf-8", "replace")


class WireStruct:
    """A fixed-size record that appears inside messages."""

    NAME: ClassVar[str]
    WIRE_SIZE: ClassVar[int]
    _S: ClassVar[struct.Struct]

    @staticmethod
    def _np_fields() -> list[Any]:
        raise NotImplementedError

    def _values(self) -> list[Any]:
        raise NotImplementedError

    @classmethod
    def _from_values(cls, v: tuple[Any, ...]) -> Self:
        raise NotImplementedError

    def encode(self) -> bytes:
        """The record's WIRE_SIZE bytes."""
        return pack(self._S, self.NAME, *self._values())

    @classmethod
    def decode(cls, data: bytes, offset: int = 0) -> Self:
        """Decode WIRE_SIZE bytes at ``offset``."""
        if len(data) - offset < cls.WIRE_SIZE:
            raise ProtocolError(f"{cls.NAME}: {len(data) - offset} bytes, need {cls.WIRE_SIZE}")
        return cls._from_values(cls._S.unpack_from(data, offset))


class Message:
    """One direction of one message: its payload as a dataclass."""

    TYPE: ClassVar[int]
    NAME: ClassVar[str]
    DIRECTION: ClassVar[str]  # "request" or "response"
    FIELDS: ClassVar[tuple[str, ...]]
    FIXED_SIZE: ClassVar[int]

    def encode(self) -> bytes:
        """The payload bytes."""
        raise NotImplementedError

    @classmethod
    def decode(cls, data: bytes) -> Self:
        """Decode a payload; ProtocolError when its length is wrong."""
        raise NotImplementedError

    @classmethod
    def _bad_length(cls, n: int) -> ProtocolError:
        return ProtocolError(f"{cls.NAME} {cls.DIRECTION}: payload of {n} bytes has the wrong length")


R = TypeVar("R", bound=Message)


class Request(Message, Generic[R]):
    """A request; ``response_class()`` says what answers it."""

    def response_class(self) -> type[R]:
        raise NotImplementedError


def numpy_dtype(cls: type[WireStruct]) -> np.dtype[np.void]:
    """The numpy structured dtype (packed, little-endian) of a struct's wire layout."""
    import numpy as np

    dt: np.dtype[np.void] = np.dtype(cls._np_fields())
    assert dt.itemsize == cls.WIRE_SIZE
    return dt


def records_array(cls: type[WireStruct], data: bytes) -> npt.NDArray[np.void]:
    """Decode a tail of ``cls`` records into a numpy structured array (one row per record)."""
    import numpy as np

    if len(data) % cls.WIRE_SIZE:
        raise ProtocolError(f"{cls.NAME} records: {len(data)} bytes is not a multiple of {cls.WIRE_SIZE}")
    return np.frombuffer(bytes(data), dtype=numpy_dtype(cls))
