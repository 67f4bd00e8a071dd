"""Seed corpus for the libFuzzer harness (tests/fuzz/fuzz_station.c) from protocol/vectors.json.

    python tools/fuzz_corpus.py OUT_DIR

One file per frame vector (its wire bytes), per malformed vector, one request of every type the
protocol defines (default field values, encoded by the generated host code, so a new message
is covered without a new vector), and request sequences as a host sends them (a 0x00 flush
before each), so that the fuzzer starts from frames that pass the CRC. Prints how many files it
wrote.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def seeds(vectors: dict[str, object]) -> list[bytes]:
    """The corpus entries: single frames, malformed frames, and request sequences."""
    frames = [v for v in vectors["frames"] if isinstance(v, dict)]  # type: ignore[union-attr]
    malformed = [v for v in vectors["malformed"] if isinstance(v, dict)]  # type: ignore[union-attr]
    requests = [bytes.fromhex(v["wire"]) for v in frames if v.get("direction") == "request"]
    out = [bytes.fromhex(v["wire"]) for v in frames]
    out += [bytes.fromhex(v["wire"]) for v in malformed]
    sys.path.insert(0, str(ROOT / "host"))
    from uwbcal.link import proto_gen as pg
    from uwbcal.link.framing import Frame, encode_frame

    for seq, cls in enumerate(sorted(pg.REQUESTS.values(), key=lambda c: c.TYPE), start=1):
        try:
            payload = cls().encode()
        except (ValueError, TypeError):
            continue
        requests.append(encode_frame(Frame(type=cls.TYPE, seq=seq, payload=payload)))
        out.append(requests[-1])
    out.append(b"".join(b"\x00" + r for r in requests))            # every request, in order
    for i in range(0, len(requests), 4):                              # and in small groups
        out.append(b"".join(b"\x00" + r for r in requests[i:i + 4]))
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python tools/fuzz_corpus.py OUT_DIR", file=sys.stderr)
        return 2
    out = Path(argv[1])
    out.mkdir(parents=True, exist_ok=True)
    vectors = json.loads((ROOT / "protocol" / "vectors.json").read_text())
    entries = seeds(vectors)
    for e in entries:
        (out / hashlib.sha1(e).hexdigest()).write_bytes(e)
    print(f"fuzz corpus: {len(entries)} seeds from protocol/vectors.json in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
