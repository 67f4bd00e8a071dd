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
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "host"))


def seeds(vectors: dict[str, object]) -> list[bytes]:
    """The corpus entries: single frames, malformed frames, and request sequences."""
    frames = [v for v in vectors["frames"] if isinstance(v, dict)]  # type: ignore[union-attr]
    malformed = [v for v in vectors["malformed"] if isinstance(v, dict)]  # type: ignore[union-attr]
    requests = [bytes.fromhex(v["wire"]) for v in frames if v.get("direction") == "request"]
    out = [bytes.fromhex(v["wire"]) for v in frames]
    out += [bytes.fromhex(v["wire"]) for v in malformed]
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
    out += sessions(pg, Frame, encode_frame)
    for i in range(0, len(requests), 4):                              # and in small groups
        out.append(b"".join(b"\x00" + r for r in requests[i:i + 4]))
    return out


def sessions(pg: Any, frame: Any, encode: Any) -> list[bytes]:
    """What a host sends in a real session, valid field by field: the paper's radio settings
    then a plan, a ranging exchange (reference and tag), fetches, a table pushed and read."""
    import numpy as np
    from uwbcal import tables

    def wire(*reqs: Any) -> bytes:
        return b"".join(b"\x00" + encode(frame(type=r.TYPE, seq=i, payload=r.encode()))
                        for i, r in enumerate(reqs, start=1))

    radio = pg.RadioConfigReq(channel=2, prf_mhz=64, preamble_len=128, data_rate=2, preamble_code=0,
                              tx_antd=16436, rx_antd=16436)
    m = tuple(float(x) for x in np.linspace(-105.0, -75.0, 6))
    curve = tables.PowerCurve(measured_dbm=m, error_s=tuple(-8e-12 * (x + 90.0) for x in m), real_dbm=m,
                              reference_real_dbm=-70.0, reference_measured_dbm=-75.0)
    data = tables.build(bytes(12), curve, created_unix=1_700_000_000)
    t = tables.decode(data)
    chunks = [pg.TableWriteReq(offset=o, data=data[o:o + tables.CHUNK])
              for o in range(0, len(data), tables.CHUNK)]
    return [
        wire(radio, pg.SeqStartReq(per_step=3, spacing_us=2000, period_us=6000, gain13=0x1F,
                                   gains2=b"\x1f\x1d"),
             pg.StatusReq(), pg.TripletsFetchReq(first_index=0, count=3), pg.StopReq()),
        wire(radio, pg.ListenReq(role=0, peer=0xFFFF, reply_us=0), pg.StatusReq(),
             pg.TripletsFetchReq(first_index=0, count=1), pg.StopReq()),
        wire(radio, pg.RangeStartReq(method=0, tag=2, count=3, period_us=20000, reply_us=2000, gain=0x1F),
             pg.StatusReq(), pg.RangesFetchReq(first_index=0, count=3), pg.StopReq()),
        wire(radio, pg.RangeStartReq(method=1, tag=2, count=2, period_us=20000, reply_us=2000, gain=0x1F)),
        wire(radio, pg.ListenReq(role=1, peer=1, reply_us=2000), pg.StatusReq(), pg.StopReq()),
        wire(*chunks, pg.TableCommitReq(length=len(data), crc32=t.crc32, force=1), pg.TableInfoReq(),
             pg.TableReadReq(offset=0, length=tables.CHUNK), pg.TableEraseReq()),
    ]


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
