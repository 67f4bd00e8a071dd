#!/usr/bin/env python3
"""Generate the protocol code from protocol/protocol.toml and protocol/messages/*.toml.

Writes (all checked in), one module of tools/protogen/ per output:
  firmware/core/proto_gen.h, firmware/core/proto_gen.c   C structs, encode/decode, dispatch  (c_code)
  host/uwbcal/link/proto_gen.py                          Python constants, dataclasses      (py_code)
  tests/firmware/vectors_gen.h                           protocol/vectors.json as C tables   (vectors)
  protocol/PROTOCOL.md (the part between the GENERATED markers)  message reference          (markdown)
  firmware/dw1000/dw1000_facts.h, host/uwbcal/dw1000_facts.py  chip facts of protocol/dw1000.toml (chip)
The definition is read and validated once, by protogen.model. The generated code imports a small
hand-written runtime instead of carrying it: uwbcal.link.wire_runtime (Python) and
firmware/core/proto_wire.h (C byte order helpers).

Usage: tools/gen_protocol.py          regenerate
       tools/gen_protocol.py --check  exit 1 naming every file that regenerating would change
                                      and every hand-written copy of a fact (protogen.copies)

Stdlib only, deterministic output (same input, same bytes).
"""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from protogen.c_code import gen_c_header, gen_c_source  # noqa: E402
from protogen.chip import gen_chip_h, gen_chip_py  # noqa: E402
from protogen.copies import find_copies  # noqa: E402
from protogen.markdown import gen_md  # noqa: E402
from protogen.model import PROTO_DIR, Protocol, ProtocolDefError, load, load_chip  # noqa: E402
from protogen.py_code import gen_python  # noqa: E402
from protogen.vectors import gen_vectors_h  # noqa: E402

__all__ = ["ROOT", "Protocol", "ProtocolDefError", "load", "main", "outputs"]

ROOT = Path(__file__).resolve().parent.parent
OUT_H = ROOT / "firmware/core/proto_gen.h"
OUT_C = ROOT / "firmware/core/proto_gen.c"
OUT_PY = ROOT / "host/uwbcal/link/proto_gen.py"
OUT_VEC = ROOT / "tests/firmware/vectors_gen.h"
OUT_MD = ROOT / "protocol/PROTOCOL.md"
OUT_CHIP_H = ROOT / "firmware/dw1000/dw1000_facts.h"
OUT_CHIP_PY = ROOT / "host/uwbcal/dw1000_facts.py"


def outputs(proto_dir: Path = PROTO_DIR) -> dict[Path, str]:
    """Every generated file's path and its text, from the definition in ``proto_dir``."""
    p = load(proto_dir)
    chip = load_chip(proto_dir)
    vec = json.loads((proto_dir / "vectors.json").read_text())
    md_now = OUT_MD.read_text() if OUT_MD.exists() else "# uwbcal wire protocol\n"
    return {
        OUT_H: gen_c_header(p),
        OUT_C: gen_c_source(p),
        OUT_PY: gen_python(p),
        OUT_VEC: gen_vectors_h(p, vec),
        OUT_MD: gen_md(p, md_now),
        OUT_CHIP_H: gen_chip_h(chip),
        OUT_CHIP_PY: gen_chip_py(chip),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true",
                    help="exit 1 if a generated file is stale or a hand-written copy of a fact exists")
    args = ap.parse_args(argv)
    try:
        outs = outputs()
    except (ProtocolDefError, KeyError, ValueError, tomllib.TOMLDecodeError) as exc:
        print(f"gen_protocol: error: {exc}", file=sys.stderr)
        return 2
    stale = []
    for path, text in outs.items():
        cur = path.read_text() if path.exists() else None
        if cur != text:
            stale.append(path)
            if not args.check:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(text)
    rel = [str(s.relative_to(ROOT)) for s in stale]
    if args.check:
        copies = find_copies(ROOT, load(), load_chip())
        for c in copies:
            print(f"gen_protocol: hand-written copy: {c} (use the generated constant)", file=sys.stderr)
        for r in rel:
            print(f"gen_protocol: stale: {r} (run `make gen`)", file=sys.stderr)
        if stale or copies:
            return 1
        print("gen_protocol: generated files are up to date; no hand-written copy of a protocol or chip fact")
        return 0
    print("gen_protocol: wrote " + (", ".join(rel) if rel else "nothing (up to date)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
