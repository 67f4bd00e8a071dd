"""Chip-facts output: protocol/dw1000.toml as firmware/dw1000/dw1000_facts.h (DW1000_<NAME>) and
host/uwbcal/dw1000_facts.py (<NAME>), for the driver, caltable.c, physics/ and the medium."""

from __future__ import annotations

from protogen.c_code import c_constants, c_enums
from protogen.model import BANNER, ChipFacts
from protogen.py_code import py_constants, py_enums

_BANNER = BANNER.replace("protocol/protocol.toml and protocol/messages", "protocol/dw1000.toml")


def gen_chip_h(chip: ChipFacts) -> str:
    """The C header of the chip facts: constants DW1000_<NAME>, named values DW_<ENUM>_<NAME>."""
    body = "\n".join(c_constants(chip.constants, "DW1000_") + c_enums(chip.enums, "DW_"))
    guard = "UWBCAL_DW1000_FACTS_H"
    return f"/* {_BANNER} */\n#ifndef {guard}\n#define {guard}\n{body}\n\n#endif\n"


def gen_chip_py(chip: ChipFacts) -> str:
    """The Python module of the chip facts: constants <NAME>, named values <ENUM>_<NAME>."""
    doc = (f'"""{_BANNER}\n\nDW1000 chip facts shared with the firmware; uwbcal.dw1000 re-exports '
           'them with the\nexpressions built on them (time unit, metres per unit)."""\n')
    body = "\n".join(py_constants(chip.constants) + py_enums(chip.enums))
    return f"{doc}\nfrom __future__ import annotations\n\nfrom typing import Final\n{body}\n"
