"""Session plans: the one gain ladder and the one sweep plan, for stations and the simulator.

A calibration sweep is P1/P2/P3 triplets, P1 and P3 at a constant TX gain, P2 stepping down
by a nominal ``step_db`` per step. :func:`gain_ladder` turns the nominal steps into TX_POWER
octets and :meth:`TripletPlan.sweep` builds the whole plan; the session runners
(sessions/runner.py, which send it to a station) and the vectorised simulator
(simulate.power_schedule, which plays it on a World) both take it from here, so
`uwbcal calibrate --step-db 3` on stations is the experiment `uwbcal paper` simulates.

Units: times in us (what the wire carries); gains are TX_POWER octets, nominal gains dB.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

from uwbcal import dw1000
from uwbcal.errors import UwbcalError

#: Highest TX_POWER octet the ladders start from: coarse 0, fine 31 (nominal +15.5 dB).
TOP_GAIN: Final = dw1000.gain_octet(0, 31)
#: Fine gain step of TX_POWER, dB.
FINE_STEP_DB: Final = 0.5


class PlanError(UwbcalError):
    """A session plan cannot be built (a gain no octet makes, a bad duration or count)."""

    exit_code = 9


def gain_ladder(top_octet: int, step_db: float, steps: int, coarse_step_db: float = 3.0) -> list[int]:
    """TX_POWER octets for nominal gains top - k * step_db, k = 0..steps-1 (dB).

    Step 0 is ``top_octet`` itself. Every nominal gain must be made exactly by some octet
    (coarse 0..6, fine 0..31 x 0.5 dB); among the octets that make it, a ``step_db`` that is a
    multiple of the coarse step takes the most coarse steps (3 dB steps use the coarse gain,
    as on the paper's cable), any other step the fewest (0.5 dB steps use the fine gain, as
    over the air). PlanError names the first step no octet makes.
    """
    if steps < 1:
        raise PlanError(f"a gain ladder needs at least one step (got {steps})")
    top = float(dw1000.gain_nominal_db(top_octet, coarse_step_db))
    ratio = step_db / coarse_step_db if coarse_step_db else 0.0
    prefer_coarse = step_db > 0 and abs(ratio - round(ratio)) < 1e-9
    coarse_order = range(6, -1, -1) if prefer_coarse else range(7)
    out = [top_octet]
    for k in range(1, steps):
        want = top - k * step_db
        for coarse in coarse_order:
            fine = (want + coarse * coarse_step_db) / FINE_STEP_DB
            if -1e-6 <= fine <= 31 + 1e-6 and abs(fine - round(fine)) < 1e-6:
                out.append(dw1000.gain_octet(coarse, int(round(fine))))
                break
        else:
            low = -6 * coarse_step_db
            raise PlanError(f"gain step {k}: no TX_POWER octet gives nominal {want:+.2f} dB (steps must "
                            f"be {FINE_STEP_DB} dB multiples within {low:+.1f}..{top:+.1f} dB; the lowest "
                            f"gain is {low:+.1f} dB at coarse step {coarse_step_db} dB)")
    return out


@dataclass(frozen=True)
class TripletPlan:
    """P1/P2/P3 triplets: ``per_step`` per entry of ``gains2``; spacing and period in us."""

    per_step: int
    spacing_us: int
    period_us: int
    gain13: int
    gains2: tuple[int, ...]

    @classmethod
    def sweep(cls, *, steps: int, per_step: int, step_db: float, spacing_us: int,
              period_us: int | None = None, gain13: int = TOP_GAIN,
              coarse_step_db: float = 3.0) -> TripletPlan:
        """The power sweep: P2's nominal gain drops ``step_db`` per step from ``gain13``
        (:func:`gain_ladder`); period P1 to next P1 defaults to :func:`default_period_us`."""
        if per_step < 1:
            raise PlanError(f"a sweep needs at least one triplet per step (got {per_step})")
        period = default_period_us(spacing_us) if period_us is None else period_us
        if spacing_us <= 0 or period < 2 * spacing_us:
            raise PlanError(f"period {period} us must be at least twice the spacing {spacing_us} us")
        return cls(per_step=per_step, spacing_us=spacing_us, period_us=period, gain13=gain13,
                   gains2=tuple(gain_ladder(gain13, step_db, steps, coarse_step_db)))

    @classmethod
    def from_settings(cls, st: dict[str, Any]) -> TripletPlan:
        """The plan stored in a session's settings (drift and calibrate sessions)."""
        return cls(per_step=int(st["per_step"]), spacing_us=int(st["spacing_us"]),
                   period_us=int(st["period_us"]), gain13=int(st["gain13"]),
                   gains2=tuple(int(g) for g in st["gains2"]))

    @property
    def total(self) -> int:
        """Triplets in the whole plan."""
        return self.per_step * len(self.gains2)


@dataclass(frozen=True)
class RangePlan:
    """``count`` exchanges of one method; period and reply delay in us; one TX gain."""

    method: str
    count: int
    period_us: int
    reply_us: int
    gain: int

    @classmethod
    def from_settings(cls, st: dict[str, Any]) -> RangePlan:
        """The plan stored in a range session's settings."""
        return cls(method=str(st["method"]), count=int(st["count"]), period_us=int(st["period_us"]),
                   reply_us=int(st["reply_us"]), gain=int(st["gain"]))


def default_period_us(spacing_us: int) -> int:
    """P1 to next P1: every message ``spacing_us`` after the previous one, as in the paper
    ("the time between every message was about 2 ms"): 3 x spacing."""
    return 3 * spacing_us


def parse_duration_us(text: str) -> int:
    """'2ms', '150us', '0.5s' or a bare number of us -> integer microseconds."""
    t = text.strip().lower()
    for suffix, scale in (("us", 1.0), ("ms", 1e3), ("s", 1e6)):
        if t.endswith(suffix):
            t, mult = t[: -len(suffix)], scale
            break
    else:
        mult = 1.0
    try:
        v = float(t) * mult
    except ValueError:
        raise PlanError(f"bad duration {text!r} (examples: 2ms, 150us, 0.5s)") from None
    if not math.isfinite(v) or v <= 0:
        raise PlanError(f"duration {text!r} must be positive")
    return int(round(v))


def parse_octet(text: str) -> int:
    """A TX_POWER octet from '0x1f', '31' or 'coarse:fine' (e.g. '0:31')."""
    try:
        if ":" in text:
            c, f = text.split(":", 1)
            return dw1000.gain_octet(int(c), int(f))
        v = int(text, 0)
    except ValueError as exc:
        raise PlanError(f"bad gain {text!r}: {exc}") from None
    if not 0 <= v <= 0xFF:
        raise PlanError(f"gain octet {text!r} out of 0..255")
    return v
