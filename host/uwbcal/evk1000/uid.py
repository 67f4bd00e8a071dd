"""The device electronic signature (RM0008 30 "Device electronic signature"): the flash
size register at 0x1FFFF7E0 (30.1, KB) and the 96-bit unique ID at 0x1FFFF7E8 (30.2),
read-only, any access width. Mapped as the system-memory page 0x1FFFF000..0x1FFFFFFF; the
rest of that page (the ROM bootloader and option bytes) is not modelled and raises BusError.
"""

from __future__ import annotations

import hashlib
from typing import Final

from uwbcal.evk1000.errors import BusError

SYSMEM_PAGE: Final = 0x1FFFF000
FSIZE_OFF: Final = 0x7E0
UID_OFF: Final = 0x7E8


def uid_for_station(station_id: int) -> bytes:
    """A deterministic 12-byte UID for an emulated station id (not a native station's)."""
    return hashlib.sha256(b"uwbcal-evk1000-uid:%d" % station_id).digest()[:12]


class DeviceSignature:
    """Flash size and unique ID."""

    name = "UID"
    base = SYSMEM_PAGE
    size = 0x1000

    def __init__(self, uid: bytes, flash_kb: int = 256) -> None:
        if len(uid) != 12:
            raise ValueError(f"the UID has 12 bytes, not {len(uid)}")
        self.bytes = bytearray(0x1000)
        self.bytes[FSIZE_OFF:FSIZE_OFF + 2] = flash_kb.to_bytes(2, "little")
        self.bytes[UID_OFF:UID_OFF + 12] = uid
        self.uid = uid

    def read(self, offset: int, width: int) -> int:
        """Little-endian bytes of the signature."""
        if not (FSIZE_OFF <= offset and offset + width <= UID_OFF + 12):
            raise BusError(f"system memory {SYSMEM_PAGE + offset:#010x} (bootloader/option bytes) "
                           "is not modelled")
        return int.from_bytes(self.bytes[offset:offset + width], "little")

    def write(self, offset: int, width: int, value: int) -> None:
        """Read-only."""
        raise BusError(f"write to the read-only device signature at {SYSMEM_PAGE + offset:#010x}")
