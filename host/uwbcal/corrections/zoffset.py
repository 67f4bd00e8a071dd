"""Z, the constant hardware offset of a TWR method, from ranging at one known distance.

Z holds everything that does not change with distance or time: TX and RX antenna delays of both
stations, and the unknown zero lines of the two power curves. With ranges (or times of flight)
measured at one known distance d, Z = d - mean(range without Z); the same estimator gives the
constant offset of each baseline (SS-TWR, DS-TWR, APS011), which a user calibrates as an antenna
delay. Two equal antenna delays (device units) follow as -Z / 2 per station when wanted.
"""

from __future__ import annotations

import numpy as np

from uwbcal import dw1000
from uwbcal.corrections.power import robust_mean
from uwbcal.dw1000 import ArrayLike, FloatArray


def z_from_known_distance_m(range_m: ArrayLike, distance_m: float) -> float:
    """Z in metres: known distance minus the robust mean of the ranges measured there (m)."""
    mean, _, n = robust_mean(range_m)
    if n == 0:
        raise ValueError("no finite range at the known distance")
    return float(distance_m - mean)


def z_m_to_s(z_m: float) -> float:
    """Z in seconds of time of flight from metres."""
    return z_m / dw1000.C_LIGHT


def antenna_delay_units(z_m: float) -> float:
    """Equal TX+RX antenna delay per station, device units, that removes Z (m).

    With true delays not configured, the measured time of flight is tof + (sum of the four TX and
    RX delays) / 2, so Z = -(D_ref + D_tag) / 2 with D a station's TX+RX delay; equal stations
    then have D = -Z / METRES_PER_UNIT units each (split between TX_ANTD and RX_ANTD as wanted).
    """
    return float(-z_m / dw1000.METRES_PER_UNIT)


def apply_z_m(range_m: ArrayLike, z_m: float) -> FloatArray:
    """Ranges plus Z, m."""
    return np.asarray(np.asarray(range_m, dtype=np.float64) + z_m, dtype=np.float64)
