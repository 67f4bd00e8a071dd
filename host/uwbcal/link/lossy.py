"""A lossy man-in-the-middle for host links: each station port gets a new pty in front of it,
and every byte crossing it, in either direction, may be dropped, duplicated or corrupted.

For tests of "nothing lost on a bad link" (in the style of Pigweed's lossy channel wrapper):

    python -m uwbcal.link.lossy --drop 1e-3 --dup 1e-3 --corrupt 1e-3 --seed 1 /dev/pts/3 /dev/pts/4
    PTY /dev/pts/9          (one line per port given, in order; runs until SIGTERM / SIGINT)

The host opens the printed ptys instead of the stations' ones. Probabilities are per byte and
per direction; a corrupted byte is XORed with a random non-zero value. Seeded: the same seed
gives the same faults for the same byte stream (arrival timing aside).
"""

from __future__ import annotations

import argparse
import os
import select
import signal
import sys
import termios
import tty
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Faults:
    """Per-byte probabilities of each fault (0..1)."""

    drop: float = 0.0
    dup: float = 0.0
    corrupt: float = 0.0


@dataclass
class FaultCounts:
    """Faults applied so far (bytes)."""

    passed: int = 0
    dropped: int = 0
    duplicated: int = 0
    corrupted: int = 0


def apply_faults(data: bytes, faults: Faults, rng: np.random.Generator, counts: FaultCounts) -> bytes:
    """``data`` with faults applied byte by byte (vectorised): one uniform draw per byte picks
    drop, duplicate, corrupt or pass."""
    if not data:
        return data
    a = np.frombuffer(data, dtype=np.uint8)
    u = rng.random(a.size)
    drop = u < faults.drop
    dup = (u >= faults.drop) & (u < faults.drop + faults.dup)
    cor = (u >= faults.drop + faults.dup) & (u < faults.drop + faults.dup + faults.corrupt)
    out = a.copy()
    if cor.any():
        out[cor] ^= rng.integers(1, 256, size=int(cor.sum()), dtype=np.uint8)
    reps = np.where(drop, 0, np.where(dup, 2, 1))
    counts.passed += int(a.size)
    counts.dropped += int(drop.sum())
    counts.duplicated += int(dup.sum())
    counts.corrupted += int(cor.sum())
    return bytes(np.repeat(out, reps))


def _raw(fd: int) -> None:
    tty.setraw(fd)
    attrs = termios.tcgetattr(fd)
    attrs[3] &= ~termios.ECHO
    termios.tcsetattr(fd, termios.TCSANOW, attrs)


@dataclass
class _Pipe:
    """One direction: bytes read from ``src`` go, with faults, to ``dst``."""

    src: int
    dst: int
    pending: bytearray = field(default_factory=bytearray)


class LossyProxy:
    """The proxy for a list of station ports: ``ports`` are the new ptys, in the same order."""

    def __init__(self, upstream: list[str], faults: Faults, seed: int = 0) -> None:
        self.faults = faults
        self.rng = np.random.default_rng(seed)
        self.counts = FaultCounts()
        self.ports: list[str] = []
        self._pipes: list[_Pipe] = []
        self._fds: list[int] = []
        for path in upstream:
            up = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            _raw(up)
            master, slave = os.openpty()
            _raw(slave)
            os.set_blocking(master, False)
            self.ports.append(os.ttyname(slave))
            self._fds += [up, master, slave]     # the slave stays open: no hang-up between hosts
            self._pipes += [_Pipe(up, master), _Pipe(master, up)]

    def run(self, stop: list[bool]) -> None:
        """Forward until ``stop[0]`` is set."""
        while not stop[0]:
            rd = [p.src for p in self._pipes]
            wr = [p.dst for p in self._pipes if p.pending]
            try:
                r, _w, _x = select.select(rd, wr, [], 0.2)
            except InterruptedError:
                continue
            for p in self._pipes:
                if p.src in r:
                    try:
                        data = os.read(p.src, 65536)
                    except (BlockingIOError, InterruptedError):
                        data = b""
                    except OSError:     # EIO: nobody has the other end open: bytes are lost
                        data = b""
                    p.pending += apply_faults(data, self.faults, self.rng, self.counts)
                if p.pending:
                    try:
                        n = os.write(p.dst, bytes(p.pending))
                        del p.pending[:n]
                    except (BlockingIOError, InterruptedError):
                        pass
                    except OSError:
                        p.pending.clear()    # no reader: like a cable nobody listens to
                    if len(p.pending) > 1 << 20:
                        del p.pending[: len(p.pending) - (1 << 20)]

    def close(self) -> None:
        for fd in self._fds:
            try:
                os.close(fd)
            except OSError:
                pass


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m uwbcal.link.lossy", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("ports", nargs="+", help="station ports to put the proxy in front of")
    ap.add_argument("--drop", type=float, default=0.0, help="probability a byte is dropped")
    ap.add_argument("--dup", type=float, default=0.0, help="probability a byte is sent twice")
    ap.add_argument("--corrupt", type=float, default=0.0, help="probability a byte is changed")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    for name in ("drop", "dup", "corrupt"):
        v = getattr(args, name)
        if not 0.0 <= v <= 1.0:
            print(f"lossy: --{name} {v} is not a probability (0..1)", file=sys.stderr)
            return 2
    try:
        proxy = LossyProxy(args.ports, Faults(args.drop, args.dup, args.corrupt), args.seed)
    except OSError as exc:
        print(f"lossy: cannot open {exc.filename}: {exc.strerror}", file=sys.stderr)
        return 2
    stop = [False]

    def _stop(*_: object) -> None:
        stop[0] = True

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    for port in proxy.ports:
        print(f"PTY {port}", flush=True)
    try:
        proxy.run(stop)
    finally:
        c = proxy.counts
        print(f"lossy: {c.passed} bytes, {c.dropped} dropped, {c.duplicated} duplicated, "
              f"{c.corrupted} corrupted", file=sys.stderr)
        proxy.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
