"""What the world model returns: transmissions and receptions, vectorised (:class:`TxBatch`,
:class:`RxBatch`) and per frame (:class:`Reception`). Times s, powers dBm, stamps device units."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


@dataclass
class TxBatch:
    """Delayed transmissions. ``stamp`` TX_STAMP (device units; modulo 2**40 if timestamp_wrap
    is on), ``stamp_unwrapped`` the same unwrapped, ``grid_units`` the start time actually used
    (DX_TIME with low 9 bits cleared, unwrapped), ``t_true_s`` true time the frame leaves the
    antenna (s), ``temp_c`` TX station temperature, ``offset_ppm`` TX clock frequency offset
    (ppm) at departure."""

    stamp: IntArray
    stamp_unwrapped: IntArray
    grid_units: IntArray
    t_true_s: FloatArray
    temp_c: FloatArray
    offset_ppm: FloatArray


@dataclass
class RxBatch:
    """Receptions at one station. ``stamp``/``stamp_unwrapped`` RX_STAMP (device units),
    ``regs`` the RX quality registers (names of columns.RX_QUALITY, int64), and the truth:
    ``t_arrival_s`` true arrival at the antenna, ``rx_dbm`` true RX power, ``est_dbm`` the chip's
    estimate, ``bias_s`` the power-dependent timestamp error (curve + station offset),
    ``error_s`` every timestamp error together (bias, delays, interference, multipath, noise),
    ``offset_ppm`` RX-minus-TX clock frequency offset, ``temp_c`` RX temperature,
    ``distance_m`` distance (or cable length), ``tof_s`` propagation time, ``detected``
    whether the power is above the radio's sensitivity."""

    stamp: IntArray
    stamp_unwrapped: IntArray
    regs: dict[str, IntArray]
    t_arrival_s: FloatArray
    rx_dbm: FloatArray
    est_dbm: FloatArray
    bias_s: FloatArray
    error_s: FloatArray
    offset_ppm: FloatArray
    temp_c: FloatArray
    distance_m: FloatArray
    tof_s: FloatArray
    detected: BoolArray


@dataclass
class Reception:
    """One frame received by one station (per-frame path): scalars of an :class:`RxBatch`."""

    rx_station: int
    stamp: int
    stamp_unwrapped: int
    regs: dict[str, int]
    t_arrival_s: float
    rx_dbm: float
    est_dbm: float
    bias_s: float
    error_s: float
    offset_ppm: float
    temp_c: float
    distance_m: float
    detected: bool
    extra: dict[str, float] = field(default_factory=dict)
