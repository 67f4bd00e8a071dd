"""Chip-facts output: protocol/dw1000.toml as firmware/dw1000/dw1000_facts.h (DW1000_<NAME>) and
host/uwbcal/dw1000_facts.py (<NAME>), for the driver, caltable.c, physics/ and the medium."""

from __future__ import annotations

from protogen.c_code import c_constants
from protogen.model import BANNER, Constant
from protogen.py_code import py_constants


def gen_chip_h(consts: dict[str, Constant]) -> str:
    """The C header of the chip facts."""
    L = [
        f"/* {BANNER.replace('protocol/protocol.toml and protocol/messages', 'protocol/dw1000.toml')} */",
        "#ifndef UWBCAL_DW1000_FACTS_H",
        "#define UWBCAL_DW1000_FACTS_H",
        *c_constants(consts, "DW1000_"),
        "",
        "#endif",
        "",
    ]
    return "\n".join(L)


def gen_chip_py(consts: dict[str, Constant]) -> str:
    """The Python module of the chip facts."""
    L = [
        f'"""{BANNER.replace("protocol/protocol.toml and protocol/messages", "protocol/dw1000.toml")}',
        "",
        "DW1000 chip facts shared with the firmware; uwbcal.dw1000 re-exports them with the",
        'expressions built on them (time unit, metres per unit)."""',
        "",
        "from __future__ import annotations",
        "",
        "from typing import Final",
        *py_constants(consts),
        "",
    ]
    return "\n".join(L)
