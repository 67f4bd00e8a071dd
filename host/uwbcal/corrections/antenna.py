"""Per-station antenna delays from ranging between three or more stations at known distances.

Two-way ranging measures tof + (D_a + D_b) / 2 for stations a and b, D the sum of a station's TX
and RX delays: only each station's combined delay is seen (APS014's three-node method has the
same limit), so the split between TX_ANTD and LDE_RXANTD is a choice: equal halves, as
Decawave's default registers (16436 each). In range units, station k adds c_k = D_k / 2 * c to
every range it takes part in, and its registers are TX_ANTD = RX_ANTD = c_k / METRES_PER_UNIT.

Model of the mean range of pair p = (a, b) at tape-measured distance d_p (m):

    r_p - d_p = c_a + c_b + b(P_p)                                      (residual -> 0)

where b(P) is the power-dependent range bias. With the stations' own power curves applied to
the ranges (the paper's E1/E2) b is already removed: ``power="none"``. Logs without RX levels
(the asil dataset) use the vendor's generic curve instead, ``power="aps011"``: b(P) =
aps011_bias_m(L1 - 20 log10(d_p)), with L1, the RX level at 1 m (dBm), fitted for the fleet.
That is a stand-in for the per-station curves the paper calibrates, with free-space loss
assumed; it is what makes delays calibrated at one geometry carry to another at other powers.

Fitting: scipy.optimize.least_squares with a robust loss (soft L1, scale 2 cm) on the per-pair
robust mean ranges; uncertainties are the square roots of the diagonal of s^2 (J^T J)^-1, s^2
the residual variance per degree of freedom (pairs minus parameters; with none left, the
pairs' own standard errors). What this cannot see: a delay error common to all stations that
the power term absorbs (one dof trades against L1), and any bias that changes between
geometries for other reasons (antenna orientation, multipath, NLOS).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from uwbcal import dw1000
from uwbcal.corrections.power import robust_mean
from uwbcal.dw1000 import FloatArray

#: Robust loss scale, m: residuals beyond it count less (soft L1).
LOSS_SCALE_M = 0.02
#: Starting RX level at 1 m for the aps011 power term, dBm.
L1_START_DBM = -75.0
#: Decawave's default antenna delay register value, device units (each of TX and RX).
DEFAULT_ANTD_UNITS = 16436


@dataclass(frozen=True)
class PairRanges:
    """Ranges (m, before any antenna delay) of one station pair at a known distance (m)."""

    a: int
    b: int
    distance_m: float
    ranges_m: FloatArray

    def mean(self) -> tuple[float, float, int]:
        """Robust mean (m), its standard error (m), the number of ranges used."""
        m, sd, n = robust_mean(self.ranges_m)
        return float(m), float(sd / math.sqrt(max(n, 1))), int(n)


@dataclass
class AntennaSolution:
    """Per-station delays c_k (m of range each station adds) with 1-sigma uncertainties."""

    stations: list[int]
    delay_m: dict[int, float]
    delay_sigma_m: dict[int, float]
    power: str
    l1_dbm: float | None = None
    l1_sigma_db: float | None = None
    residuals_m: dict[str, float] = field(default_factory=dict)
    dof: int = 0

    def antd_units(self, station: int) -> int:
        """TX_ANTD = LDE_RXANTD register value (device units) for ``station`` (equal split)."""
        return int(round(self.delay_m[station] / dw1000.METRES_PER_UNIT))

    def bias_m(self, a: int, b: int, distance_m: float) -> float:
        """Predicted range minus distance of pair (a, b) at ``distance_m`` (m)."""
        out = self.delay_m[a] + self.delay_m[b]
        if self.power == "aps011" and self.l1_dbm is not None:
            out += float(dw1000.aps011_bias_m(self.l1_dbm - 20.0 * math.log10(distance_m)))
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON form (station keys as strings)."""
        return {"stations": self.stations, "power": self.power,
                "delay_m": {str(k): v for k, v in self.delay_m.items()},
                "delay_sigma_m": {str(k): v for k, v in self.delay_sigma_m.items()},
                "antd_units": {str(k): self.antd_units(k) for k in self.stations},
                "l1_dbm": self.l1_dbm, "l1_sigma_db": self.l1_sigma_db,
                "residuals_m": self.residuals_m, "dof": self.dof}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> AntennaSolution:
        """Inverse of :meth:`to_dict`."""
        return cls(stations=[int(s) for s in d["stations"]], power=str(d["power"]),
                   delay_m={int(k): float(v) for k, v in d["delay_m"].items()},
                   delay_sigma_m={int(k): float(v) for k, v in d["delay_sigma_m"].items()},
                   l1_dbm=None if d.get("l1_dbm") is None else float(d["l1_dbm"]),
                   l1_sigma_db=None if d.get("l1_sigma_db") is None else float(d["l1_sigma_db"]),
                   residuals_m=dict(d.get("residuals_m") or {}), dof=int(d.get("dof") or 0))


def _pair_key(a: int, b: int) -> str:
    return f"{min(a, b)}-{max(a, b)}"


def merge_directions(pairs: Sequence[PairRanges]) -> list[PairRanges]:
    """Both directions of a pair at one distance as one (their ranges pooled); sorted by station
    ids, then distance."""
    by: dict[tuple[int, int, float], list[PairRanges]] = {}
    for p in pairs:
        by.setdefault((min(p.a, p.b), max(p.a, p.b), round(p.distance_m, 4)), []).append(p)
    return [PairRanges(a, b, ps[0].distance_m, np.concatenate([p.ranges_m for p in ps]))
            for (a, b, _d), ps in sorted(by.items())]


def _names(merged: Sequence[PairRanges]) -> list[str]:
    """``"a-b"`` per pair, ``"a-b@d m"`` where a pair was ranged at several distances."""
    count: dict[str, int] = {}
    for p in merged:
        count[_pair_key(p.a, p.b)] = count.get(_pair_key(p.a, p.b), 0) + 1
    return [_pair_key(p.a, p.b) + (f"@{p.distance_m:g}m" if count[_pair_key(p.a, p.b)] > 1 else "")
            for p in merged]


def solve(pairs: Sequence[PairRanges], power: str = "none") -> AntennaSolution:
    """Per-station delays (and L1 with ``power="aps011"``) from pairs at known distances.

    ValueError when the pairs cannot determine every station (fewer independent pairs than
    unknowns, or a station in no pair).
    """
    from scipy.optimize import least_squares

    if power not in ("none", "aps011"):
        raise ValueError(f"power model {power!r}: 'none' or 'aps011'")
    merged = merge_directions(pairs)
    stations = sorted({s for p in merged for s in (p.a, p.b)})
    n_par = len(stations) + (1 if power == "aps011" else 0)
    if len(stations) < 3 or len(merged) < n_par:
        raise ValueError(f"{len(merged)} station pairs cannot determine {n_par} unknowns: antenna delays "
                         "need three or more stations and at least as many pairs as unknowns")
    distinct = {(p.a, p.b) for p in merged}
    if len(distinct) < len(stations):
        raise ValueError(f"{len(distinct)} distinct station pairs cannot determine {len(stations)} stations' "
                         "delays: range every station with at least two others")
    idx = {s: i for i, s in enumerate(stations)}
    stats = [p.mean() for p in merged]
    y = np.array([m - p.distance_m for p, (m, _, _) in zip(merged, stats, strict=True)])
    sem = np.array([max(s, 1e-4) for _, s, _ in stats])
    logd = np.log10([p.distance_m for p in merged])
    ia = np.array([idx[p.a] for p in merged])
    ib = np.array([idx[p.b] for p in merged])

    def model(x: FloatArray) -> FloatArray:
        out = x[ia] + x[ib]
        if power == "aps011":
            out = out + dw1000.aps011_bias_m(x[-1] - 20.0 * logd)
        return np.asarray(out, dtype=np.float64)

    x0 = np.full(n_par, float(np.median(y)) / 2.0)
    if power == "aps011":
        x0[-1] = L1_START_DBM
    fit = least_squares(lambda x: y - model(x), x0, loss="soft_l1", f_scale=LOSS_SCALE_M)
    res = y - model(fit.x)
    dof = len(merged) - n_par
    s2 = float(np.sum(res**2) / dof) if dof > 0 else float(np.mean(sem**2))
    jtj = fit.jac.T @ fit.jac
    cov = np.linalg.pinv(jtj) * s2
    sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return AntennaSolution(
        stations=stations, power=power,
        delay_m={s: float(fit.x[idx[s]]) for s in stations},
        delay_sigma_m={s: float(sig[idx[s]]) for s in stations},
        l1_dbm=float(fit.x[-1]) if power == "aps011" else None,
        l1_sigma_db=float(sig[-1]) if power == "aps011" else None,
        residuals_m={k: float(r) for k, r in zip(_names(merged), res, strict=True)}, dof=dof)


def default_solution(stations: Sequence[int], delay_m: float | None = None) -> AntennaSolution:
    """The uncalibrated baseline: every station at Decawave's default registers (16436 each),
    or ``delay_m`` (m; 0 for ranges whose stations already had the default registers programmed)."""
    c = DEFAULT_ANTD_UNITS * dw1000.METRES_PER_UNIT if delay_m is None else delay_m
    return AntennaSolution(stations=list(stations), power="none", delay_m={s: c for s in stations},
                           delay_sigma_m={s: 0.0 for s in stations})


def prediction_errors(sol: AntennaSolution, pairs: Sequence[PairRanges]) -> dict[str, float]:
    """Per pair (``"a-b"``, ``"a-b@d m"`` at several distances): corrected range minus
    tape-measured distance, m (robust means)."""
    merged = merge_directions(pairs)
    out = {}
    for name, p in zip(_names(merged), merged, strict=True):
        m, _, _ = p.mean()
        out[name] = m - sol.bias_m(p.a, p.b, p.distance_m) - p.distance_m
    return out
