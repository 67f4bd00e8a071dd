"""Where a power calibration is valid, and whether ranging stayed there.

A power curve is measured over the RX levels its sweep reached: outside that span the curve is
held at its end value (numpy.interp clamps), which is an extrapolation the user must know about.
The chip's RX level estimate is right only below about -85 dBm (the paper); the measured-vs-real
map is fitted there. :class:`Validity` records both for one station; it travels with the table
(T.json ``validity``; the swept span is also the first and last curve point of the table bytes,
so a table pulled from a station still carries it). :func:`twr_coverage` counts, per station and
correction, how many ranging records fell inside the swept span, and words a warning with the
two ways out: accept the stated extrapolation, or re-calibrate closer (a command to do it).

Units: levels dBm, distances m.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any, TypeVar

import numpy as np

from uwbcal.corrections.power import PowerCalibration, PowerCurve
from uwbcal.dw1000 import FloatArray

T = TypeVar("T")

#: Levels this close to the swept span's ends (dB) still count as inside (level noise ~0.2 dB).
EDGE_DB = 0.5
#: Fraction of records outside the swept span above which a warning is given.
WARN_FRACTION = 0.05


@dataclass(frozen=True)
class Validity:
    """Span of one station's power calibration.

    ``swept_measured_dbm``: measured RX levels (lowest, highest) the sweep reached;
    ``swept_real_dbm``: the estimated real RX power there; ``trusted_below_dbm``: measured level
    below which the level estimate was taken as right for the measured-vs-real fit (None when
    unknown, e.g. a table pulled from a station); ``calibrated_at_m``: the sweep's TX-RX distance
    (None when not recorded).
    """

    station: int | None
    swept_measured_dbm: tuple[float, float]
    swept_real_dbm: tuple[float, float]
    trusted_below_dbm: float | None = None
    calibrated_at_m: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        d = asdict(self)
        d["swept_measured_dbm"] = list(self.swept_measured_dbm)
        d["swept_real_dbm"] = list(self.swept_real_dbm)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Validity:
        """Inverse of :meth:`to_dict`."""
        def opt(k: str) -> float | None:
            v = d.get(k)
            return None if v is None else float(v)

        sm, sr = d["swept_measured_dbm"], d["swept_real_dbm"]
        return cls(station=None if d.get("station") is None else int(d["station"]),
                   swept_measured_dbm=(float(sm[0]), float(sm[1])),
                   swept_real_dbm=(float(sr[0]), float(sr[1])),
                   trusted_below_dbm=opt("trusted_below_dbm"), calibrated_at_m=opt("calibrated_at_m"))


def of_curve(curve: PowerCurve, trusted_below_dbm: float | None = None,
             calibrated_at_m: float | None = None) -> Validity:
    """The validity of a curve (its measured and real axes' ends)."""
    return Validity(station=curve.rx_station,
                    swept_measured_dbm=(float(curve.measured_dbm[0]), float(curve.measured_dbm[-1])),
                    swept_real_dbm=(float(min(curve.real_dbm)), float(max(curve.real_dbm))),
                    trusted_below_dbm=trusted_below_dbm, calibrated_at_m=calibrated_at_m)


def of_calibration(cal: PowerCalibration, calibrated_at_m: float | None = None) -> Validity:
    """The validity of a power calibration (curve span and the level estimate's threshold)."""
    return of_curve(cal.curve, cal.threshold_dbm, calibrated_at_m)


def loudest_per_station(items: Iterable[tuple[int, PowerCurve, T]]) -> dict[int, tuple[PowerCurve, T]]:
    """One curve per receiving station from (station, curve, payload) items: the one whose sweep
    reached the highest measured level (the closest transmitter of a fleet session), so that
    ranging at every distance of the fleet stays inside it; curves agree where they overlap."""
    out: dict[int, tuple[PowerCurve, T]] = {}
    for sid, curve, payload in items:
        if sid not in out or curve.measured_dbm[-1] > out[sid][0].measured_dbm[-1]:
            out[sid] = (curve, payload)
    return out


def level_coverage(levels: FloatArray, v: Validity) -> dict[str, Any]:
    """Records of ``levels`` (measured dBm) inside, above and below the swept span."""
    x = np.asarray(levels, dtype=np.float64)
    ok = np.isfinite(x)
    lo, hi = v.swept_measured_dbm
    above = ok & (x > hi + EDGE_DB)
    below = ok & (x < lo - EDGE_DB)
    return {"n": int(ok.sum()), "n_inside": int((ok & ~above & ~below).sum()), "n_above": int(above.sum()),
            "n_below": int(below.sum()),
            "level_median_dbm": float(np.median(x[ok])) if ok.any() else float("nan"),
            "level_max_dbm": float(np.max(x[ok])) if ok.any() else float("nan"),
            "swept_measured_dbm": [lo, hi]}


def twr_coverage(tag: FloatArray | None, ref: FloatArray | None, lv_tag: FloatArray | None,
                 lv_ref: FloatArray | None, validity: Mapping[int, Validity],
                 distance_m: FloatArray | None = None) -> list[dict[str, Any]]:
    """Per station and role, how many ranging records used its curve inside the swept span.

    ``tag``/``ref`` are the station id columns, ``lv_tag`` the tag's measured level of M1 (E1),
    ``lv_ref`` the reference's of M2 (E2), ``distance_m`` the declared distance of each record.
    Each entry: station, role, counts, and ``warning`` (text, or None) when more than
    :data:`WARN_FRACTION` of them lie outside; ``closer_m`` is the shortest declared distance
    of the records above the span (re-calibrating there covers them), None when unknown.

    The measured level saturates above about -85 dBm, so how far above the span a record lies
    is not a reliable distance; the declared ranging distance is used instead.
    """
    out: list[dict[str, Any]] = []
    for role, ids, lv in (("tag (E1)", tag, lv_tag), ("reference (E2)", ref, lv_ref)):
        if ids is None or lv is None:
            continue
        for sid, v in sorted(validity.items()):
            sel = ids == sid
            if not sel.any():
                continue
            cov = level_coverage(lv[sel], v)
            x = np.asarray(lv[sel], dtype=np.float64)
            above = x > v.swept_measured_dbm[1] + EDGE_DB
            n_out = cov["n_above"] + cov["n_below"]
            entry: dict[str, Any] = {"station": sid, "role": role, **cov, "warning": None, "closer_m": None}
            if cov["n"] and n_out > WARN_FRACTION * cov["n"]:
                lo, hi = v.swept_measured_dbm
                side = "above" if cov["n_above"] >= cov["n_below"] else "below"
                text = (f"station {sid} as {role}: {n_out} of {cov['n']} records read levels outside its "
                        f"calibrated span {lo:.1f} .. {hi:.1f} dBm "
                        f"(median {cov['level_median_dbm']:.1f} dBm, {side}): there its power correction "
                        f"is extrapolated as the curve's end value")
                closer = None
                if side == "above" and distance_m is not None:
                    da = np.asarray(distance_m, dtype=np.float64)[sel][above]
                    da = da[np.isfinite(da)]
                    closer = float(np.min(da)) if da.size else None
                if closer is not None:
                    entry["closer_m"] = round(closer, 3)
                    was = ("" if v.calibrated_at_m is None
                           else f" (it was calibrated at {v.calibrated_at_m:g} m)")
                    text += (f"; to cover them re-calibrate at {closer:g} m or closer{was}: "
                             f"uwbcal calibrate --tx PEER --rx STATION{sid} --distance {closer:g} ...")
                elif side == "above":
                    text += "; to cover them re-calibrate with the stations closer together"
                else:
                    text += "; to cover them re-calibrate with more gain steps (--steps) or farther apart"
                entry["warning"] = text
            out.append(entry)
    return out
