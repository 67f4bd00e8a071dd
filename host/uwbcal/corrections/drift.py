"""Clock drift correction of P1/P2/P3 triplets (the paper's eq. 1) and the carrier-integrator baseline.

A TX station sends P1, P2, P3 at TX-clock times ``tx1 < tx2 < tx3``; the RX station stamps them
``rx1, rx2, rx3`` on its own clock. With ``dT_ab`` a timestamp difference (modulo 2**40) and
``C_ab = dT_rx(a,b) - dT_tx(a,b)`` (the clock drift error, device units):

    C'_12 = C_12 - C_13 / dT_tx(1,3) * dT_tx(1,2)                                  (eq. 1)

Derivation (a measured RX timestamp = true arrival on the RX clock + E_k, E_k the power-dependent
timestamp error, RX clock = (1 + eps) * TX clock + phi): ``C_12 = eps dT_tx12 + E2 - E1`` and
``C_13 = eps dT_tx13 + E3 - E1``. With E3 = E1 (P1 and P3 share power) C_13 / dT_tx13 = eps exactly,
so C'_12 = E2 - E1: zero for a drift run, the timestamp error of P2 relative to P1 for a power
sweep. No carrier integrator is involved.

The baseline a user compares against estimates eps from the carrier integrator (DRX_CAR_INT) of
the received messages. A positive integrator means the receiver's clock runs fast [UM], so
``ppm = dw1000.car_int_to_ppm(car_int)`` (which multiplies by -1e6 / f_carrier) is the
TX-minus-RX offset, as in Decawave's SS-TWR example (``rtd_resp * (1 - ppm * 1e-6)``) and in
uwbcal.physics: eps = -ppm * 1e-6 and ``C''_12 = C_12 + ppm * 1e-6 * dT_tx12``. The paper shows
the integrator moves with the received signal power.

All functions take numpy arrays of raw device-unit timestamps (any integer type, possibly
wrapped at 2**40) and return float64 arrays; 1e6 triplets take a few tens of milliseconds.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from uwbcal import dw1000
from uwbcal.dw1000 import ArrayLike, FloatArray


@dataclass(frozen=True)
class TripletDiffs:
    """Timestamp differences of triplets, device units (float64, exact for |d| < 2**53)."""

    dtx12: FloatArray
    dtx13: FloatArray
    drx12: FloatArray
    drx13: FloatArray


def triplet_diffs(tx1: ArrayLike, tx2: ArrayLike, tx3: ArrayLike,
                  rx1: ArrayLike, rx2: ArrayLike, rx3: ArrayLike) -> TripletDiffs:
    """Differences dT_tx(1,2), dT_tx(1,3), dT_rx(1,2), dT_rx(1,3), device units, modulo 2**40."""
    return TripletDiffs(
        dtx12=dw1000.wrap_diff(tx2, tx1).astype(np.float64),
        dtx13=dw1000.wrap_diff(tx3, tx1).astype(np.float64),
        drx12=dw1000.wrap_diff(rx2, rx1).astype(np.float64),
        drx13=dw1000.wrap_diff(rx3, rx1).astype(np.float64),
    )


def c12_uncorrected(d: TripletDiffs) -> FloatArray:
    """C_12 = dT_rx(1,2) - dT_tx(1,2), device units: drift error plus E2 - E1, no correction."""
    return np.asarray(d.drx12 - d.dtx12, dtype=np.float64)


def c12_corrected(d: TripletDiffs) -> FloatArray:
    """C'_12 of eq. 1, device units: C_12 - C_13 / dT_tx(1,3) * dT_tx(1,2) (= E2 - E1)."""
    c13 = d.drx13 - d.dtx13
    return np.asarray((d.drx12 - d.dtx12) - c13 / d.dtx13 * d.dtx12, dtype=np.float64)


def drift_ratio(d: TripletDiffs) -> FloatArray:
    """Clock drift estimate eps = C_13 / dT_tx(1,3) (dimensionless; 1e-6 = 1 ppm, RX faster > 0)."""
    return np.asarray((d.drx13 - d.dtx13) / d.dtx13, dtype=np.float64)


def c12_carrier_integrator(d: TripletDiffs, car_int: ArrayLike, channel: int = 2,
                           data_rate_kbps: int = 6810) -> FloatArray:
    """Baseline: C_12 corrected with the carrier integrator, device units.

    ``car_int`` is the DRX_CAR_INT value (sign-extended) to use per triplet, e.g. that of P1, of
    P2, or their mean; eps = -car_int_to_ppm(car_int) * 1e-6 (RX relative to TX) and
    C''_12 = C_12 - eps * dT_tx(1,2).
    """
    eps = -dw1000.car_int_to_ppm(car_int, channel, data_rate_kbps) * 1e-6
    return np.asarray((d.drx12 - d.dtx12) - eps * d.dtx12, dtype=np.float64)


def units_to_m(units: ArrayLike) -> FloatArray:
    """Device units to metres of light travel (1 unit = 4.69 mm)."""
    return np.asarray(np.asarray(units, dtype=np.float64) * dw1000.METRES_PER_UNIT, dtype=np.float64)


def units_to_s(units: ArrayLike) -> FloatArray:
    """Device units to seconds (1 unit = 15.65 ps)."""
    return np.asarray(np.asarray(units, dtype=np.float64) * dw1000.TIME_UNIT_S, dtype=np.float64)


@dataclass(frozen=True)
class ResidualStats:
    """Summary of a residual series, metres: mean, std, standard error of the mean, count."""

    mean_m: float
    std_m: float
    sem_m: float
    n: int

    def to_dict(self) -> dict[str, float | int]:
        """Plain dict for JSON."""
        return asdict(self)


def residual_stats(residual_m: ArrayLike) -> ResidualStats:
    """Mean, std (ddof=1), standard error of the mean, metres, of the finite values."""
    r = np.asarray(residual_m, dtype=np.float64)
    r = r[np.isfinite(r)]
    n = int(r.size)
    if n == 0:
        return ResidualStats(float("nan"), float("nan"), float("nan"), 0)
    std = float(np.std(r, ddof=1)) if n > 1 else 0.0
    return ResidualStats(float(np.mean(r)), std, float(std / np.sqrt(n)), n)


def noise_floor_m(timestamp_noise_s: float, n: int, ratio12: float = 0.5) -> float:
    """Theoretical standard error of the mean C'_12, metres, for white RX timestamp noise.

    C'_12 = rx2 - rx1 - r (rx3 - rx1) + TX terms with r = dT_tx12 / dT_tx13, so one C'_12 has
    std sigma * sqrt(1 + (1 - r)**2 + r**2) (sigma = per-timestamp noise, s); the mean of n has
    that over sqrt(n). The 15.65 ps quantisation (uniform, sigma = unit / sqrt(12)) is added in
    quadrature to ``timestamp_noise_s``.
    """
    q = dw1000.TIME_UNIT_S / np.sqrt(12.0)
    sigma = float(np.hypot(timestamp_noise_s, q))
    k = float(np.sqrt(1.0 + (1.0 - ratio12) ** 2 + ratio12**2))
    return sigma * k * dw1000.C_LIGHT / float(np.sqrt(max(n, 1)))


@dataclass(frozen=True)
class DriftAnalysis:
    """Drift-run analysis: C_12 residual without correction, with eq. 1, and with the integrator.

    ``windows_*`` are means over consecutive windows of the run (metres), showing warm-up.
    """

    uncorrected: ResidualStats
    corrected: ResidualStats
    carrier_integrator: ResidualStats | None
    drift_ppm_mean: float
    drift_ppm_first: float
    drift_ppm_last: float
    spacing_s: float
    statistical_floor_m: float
    window_t_s: list[float]
    window_uncorrected_m: list[float]
    window_corrected_m: list[float]
    window_carrier_integrator_m: list[float] | None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON (nested stats as dicts)."""
        out = asdict(self)
        return out


def _window_means(x: FloatArray, n_windows: int) -> list[float]:
    if x.size == 0:
        return []
    k = max(1, min(n_windows, x.size))
    return [float(np.mean(c)) for c in np.array_split(x, k)]


def analyze_drift(tx1: ArrayLike, tx2: ArrayLike, tx3: ArrayLike,
                  rx1: ArrayLike, rx2: ArrayLike, rx3: ArrayLike,
                  t_s: ArrayLike | None = None, car_int1: ArrayLike | None = None,
                  car_int2: ArrayLike | None = None, channel: int = 2, data_rate_kbps: int = 6810,
                  n_windows: int = 20) -> DriftAnalysis:
    """Analyse a drift run (constant gains): residual C_12 in metres with and without eq. 1.

    The carrier-integrator baseline is computed when ``car_int1`` and/or ``car_int2`` are given
    (their mean when both): it is the correction the paper argues against.
    """
    d = triplet_diffs(tx1, tx2, tx3, rx1, rx2, rx3)
    unc = units_to_m(c12_uncorrected(d))
    cor = units_to_m(c12_corrected(d))
    ci: FloatArray | None = None
    ci_list = [np.asarray(c, dtype=np.float64) for c in (car_int1, car_int2) if c is not None]
    if ci_list:
        car = ci_list[0] if len(ci_list) == 1 else 0.5 * (ci_list[0] + ci_list[1])
        if np.all(np.isfinite(car)):
            ci = units_to_m(c12_carrier_integrator(d, car, channel, data_rate_kbps))
    eps_ppm = drift_ratio(d) * 1e6
    n = int(cor.size)
    tt = np.asarray(t_s, dtype=np.float64) if t_s is not None else np.arange(n, dtype=np.float64)
    cs = residual_stats(cor)
    first = eps_ppm[: max(1, n // 20)]
    last = eps_ppm[-max(1, n // 20):]
    return DriftAnalysis(
        uncorrected=residual_stats(unc),
        corrected=cs,
        carrier_integrator=residual_stats(ci) if ci is not None else None,
        drift_ppm_mean=float(np.mean(eps_ppm)) if n else float("nan"),
        drift_ppm_first=float(np.mean(first)) if n else float("nan"),
        drift_ppm_last=float(np.mean(last)) if n else float("nan"),
        spacing_s=float(np.median(d.dtx12)) * dw1000.TIME_UNIT_S if n else float("nan"),
        statistical_floor_m=cs.sem_m,
        window_t_s=_window_means(tt, n_windows),
        window_uncorrected_m=_window_means(unc, n_windows),
        window_corrected_m=_window_means(cor, n_windows),
        window_carrier_integrator_m=_window_means(ci, n_windows) if ci is not None else None,
    )
