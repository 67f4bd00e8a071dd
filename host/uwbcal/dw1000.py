"""DW1000 chip facts used across uwbcal (physics, medium, corrections, importers).

Sources: Decawave DW1000 User Manual (sections on system time, TX power, RX level estimate
4.7.2, carrier integrator) and APS011, as gathered in ../shared/reference/dw1000-evk1000.md.
Where sources disagree the value is a parameter with the alternatives named, never a silent
constant.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000_facts as facts

FloatArray = npt.NDArray[np.float64]
ArrayLike = npt.ArrayLike

# The numbers the firmware shares come from protocol/dw1000.toml (generated dw1000_facts).
#: Speed of light in vacuum, m/s.
C_LIGHT: Final = facts.C_LIGHT
#: Time units per second: 128 * 499.2 MHz.
TICK_HZ: Final = facts.TICK_HZ
#: One DW1000 time unit, s: 1 / (128 * 499.2 MHz), about 15.65 ps.
TIME_UNIT_S: Final = 1.0 / TICK_HZ
#: Timestamps are 40-bit counters: they wrap every 2**40 units (about 17.2 s).
TIMESTAMP_MOD: Final = 1 << facts.TIMESTAMP_BITS
#: Delayed TX ignores the low 9 bits of DX_TIME: transmissions start on a 512-unit grid.
DELAYED_TX_GRID: Final = facts.DELAYED_TX_GRID
#: Metres of light travel per time unit (about 4.69 mm).
METRES_PER_UNIT: Final = C_LIGHT * TIME_UNIT_S
#: Radio settings of the chip: channels, PRFs (MHz), preamble lengths (symbols).
CHANNELS: Final = facts.CHANNELS
PRFS: Final = facts.PRFS
PREAMBLE_LENGTHS: Final = facts.PREAMBLE_LENGTHS
#: RX_TTCKI per PRF (MHz): the time tracking interval depends only on the PRF (UM 7.2.21).
RX_TTCKI_BY_PRF: Final[dict[int, int]] = {16: facts.RX_TTCKI_PRF16, 64: facts.RX_TTCKI_PRF64}
#: SAR temperature: degC per LSB and the reference temperature of the OTP reading (UM 6.4:
#: T = (SAR_LTEMP - OTP Vtemp@23C) x 1.14 + 23). Decawave's driver uses the same 1.14.
SAR_DEGC_PER_LSB: Final = facts.SAR_TEMP_DEGC_PER_LSB
SAR_REF_DEGC: Final = facts.SAR_TEMP_REF_DEGC

#: Carrier centre frequency per channel, Hz.
CHANNEL_FREQ_HZ: Final[dict[int, float]] = {
    1: 3494.4e6, 2: 3993.6e6, 3: 4492.8e6, 4: 3993.6e6, 5: 6489.6e6, 7: 6489.6e6,
}

#: Constant A of the RX level estimate, dBm, per PRF (MHz). For 16 MHz PRF older manuals and
#: much public code use 113.77, later manuals 115.72: pass ``a_dbm`` explicitly to choose.
RX_LEVEL_A_DBM: Final[dict[int, float]] = {64: 121.74, 16: 115.72}
RX_LEVEL_A_DBM_16_OLD: Final = 113.77

#: Data rates, kb/s, indexed by their register code (TXBR/RXBR, cal_table.data_rate).
DATA_RATES_KBPS: Final = facts.DATA_RATES_KBPS
#: SFD symbols RXPACC includes when it equals RXPACC_NOSAT (standard SFD), per data rate (kb/s).
RXPACC_SFD_CORR: Final[dict[int, int]] = {
    r: facts.RXPACC_SFD_CORR_110K if code == 0 else facts.RXPACC_SFD_CORR
    for code, r in enumerate(DATA_RATES_KBPS)
}

#: DEV_ID register value of a DW1000.
DEV_ID: Final = facts.DEV_ID_VALUE


def wrap_diff(later: ArrayLike, earlier: ArrayLike) -> npt.NDArray[np.int64]:
    """Difference of two timestamps modulo 2**40, in device units, in [-2**39, 2**39)."""
    d = (np.asarray(later, dtype=np.int64) - np.asarray(earlier, dtype=np.int64)) % TIMESTAMP_MOD
    return np.where(d >= TIMESTAMP_MOD // 2, d - TIMESTAMP_MOD, d).astype(np.int64)


def rxpacc_n(rxpacc: ArrayLike, rxpacc_nosat: ArrayLike | None, data_rate_kbps: int = 6810) -> FloatArray:
    """The preamble count N of the RX level estimate, symbols: RXPACC, less the SFD symbols it
    counts when it equals RXPACC_NOSAT (user manual, RXPACC_NOSAT; standard SFD), floored at 0.

    ``rxpacc_nosat`` None (not recorded): RXPACC as read. The firmware's caltable_rxpacc_n is the
    same rule on the same generated constants.
    """
    n = np.asarray(rxpacc, dtype=np.float64)
    if rxpacc_nosat is None:
        return n
    corr = RXPACC_SFD_CORR[data_rate_kbps]
    same = n == np.asarray(rxpacc_nosat, dtype=np.float64)
    return np.asarray(np.where(same, np.maximum(n - corr, 0.0), n), dtype=np.float64)


def rx_level_dbm(cir_pwr: ArrayLike, rxpacc: ArrayLike, prf_mhz: int = 64,
                 a_dbm: float | None = None) -> FloatArray:
    """Estimated RX level, dBm (user manual 4.7.2): 10 log10(C * 2**17 / N**2) - A.

    ``cir_pwr`` is RX_FQUAL.CIR_PWR, ``rxpacc`` the (corrected) preamble accumulation count N.
    """
    a = RX_LEVEL_A_DBM[prf_mhz] if a_dbm is None else a_dbm
    c = np.asarray(cir_pwr, dtype=np.float64)
    n = np.asarray(rxpacc, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.asarray(10.0 * np.log10(c * 2.0**17 / n**2) - a, dtype=np.float64)


def cir_pwr_for_level(level_dbm: ArrayLike, rxpacc: ArrayLike, prf_mhz: int = 64,
                      a_dbm: float | None = None) -> FloatArray:
    """Inverse of :func:`rx_level_dbm`: the CIR_PWR value (unrounded) that reads ``level_dbm``."""
    a = RX_LEVEL_A_DBM[prf_mhz] if a_dbm is None else a_dbm
    n = np.asarray(rxpacc, dtype=np.float64)
    return np.asarray(10.0 ** ((np.asarray(level_dbm, dtype=np.float64) + a) / 10.0) * n**2 / 2.0**17)


def fp_power_dbm(f1: ArrayLike, f2: ArrayLike, f3: ArrayLike, rxpacc: ArrayLike, prf_mhz: int = 64,
                 a_dbm: float | None = None) -> FloatArray:
    """First-path power, dBm (user manual 4.7.1): 10 log10((F1^2+F2^2+F3^2) / N^2) - A."""
    a = RX_LEVEL_A_DBM[prf_mhz] if a_dbm is None else a_dbm
    s = sum(np.asarray(f, dtype=np.float64) ** 2 for f in (f1, f2, f3))
    n = np.asarray(rxpacc, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.asarray(10.0 * np.log10(s / n**2) - a, dtype=np.float64)


def car_int_hz_per_lsb(data_rate_kbps: int = 6810) -> float:
    """Carrier integrator scale, Hz per LSB: 998.4e6 / 2 / 1024 / 131072 (8192 at 110 kb/s)."""
    div = 8192 if data_rate_kbps == 110 else 1024
    return 998.4e6 / 2.0 / div / 131072.0


def car_int_to_ppm(car_int: ArrayLike, channel: int = 2, data_rate_kbps: int = 6810) -> FloatArray:
    """Clock offset from DRX_CAR_INT, ppm: offset_Hz * (-1e6 / f_carrier).

    A positive integrator means the receiver's local clock runs faster (user manual), which
    this returns as a negative value: the result is the transmitter's clock rate minus the
    receiver's, in ppm (the convention of Decawave's single-sided TWR example code).
    """
    hz = np.asarray(car_int, dtype=np.float64) * car_int_hz_per_lsb(data_rate_kbps)
    return np.asarray(hz * (-1e6 / CHANNEL_FREQ_HZ[channel]), dtype=np.float64)


def ppm_to_car_int(ppm: ArrayLike, channel: int = 2, data_rate_kbps: int = 6810) -> FloatArray:
    """Inverse of :func:`car_int_to_ppm` (unrounded)."""
    hz = np.asarray(ppm, dtype=np.float64) * CHANNEL_FREQ_HZ[channel] / -1e6
    return np.asarray(hz / car_int_hz_per_lsb(data_rate_kbps), dtype=np.float64)


def gain_octet(coarse: int, fine_half_db: int) -> int:
    """TX_POWER octet from coarse setting (0 highest .. 6 lowest, 7 off) and fine 0.5 dB steps (0..31)."""
    if not 0 <= coarse <= 7:
        raise ValueError(f"coarse gain {coarse} outside 0..7")
    if not 0 <= fine_half_db <= 31:
        raise ValueError(f"fine gain {fine_half_db} outside 0..31 (0.5 dB steps)")
    return (coarse << 5) | fine_half_db


def gain_nominal_db(octet: ArrayLike, coarse_step_db: float = 3.0) -> FloatArray:
    """Nominal TX gain of a TX_POWER octet, dB relative to coarse 0 / fine 0.

    The coarse step is 3 dB in older manuals and public drivers, 2.5 dB in a later revision:
    a parameter. Coarse 7 (output off) gives -inf.
    """
    o = np.asarray(octet, dtype=np.int64)
    coarse = (o >> 5) & 7
    fine = o & 31
    g = fine * 0.5 - coarse * coarse_step_db
    return np.asarray(np.where(coarse == 7, -np.inf, g), dtype=np.float64)


#: Decawave APS011 range bias (cm, positive = reported range too long) against RX level
#: (dBm) for 500 MHz channels, as quoted in public drivers. One vendor's average for its
#: own boards; the paper shows every station differs.
APS011_LEVEL_DBM: Final = tuple(float(x) for x in range(-61, -95, -2))
APS011_BIAS_CM_PRF64: Final = (-11.0, -10.4, -10.0, -9.3, -8.2, -6.9, -5.1, -2.7, 0.0, 2.1, 3.5,
                               4.2, 4.9, 6.2, 7.1, 7.6, 8.1)


def aps011_bias_m(level_dbm: ArrayLike) -> FloatArray:
    """APS011 range bias, m, interpolated in RX level (PRF 64 MHz), clamped at the table ends."""
    x = np.asarray(APS011_LEVEL_DBM[::-1])
    y = np.asarray(APS011_BIAS_CM_PRF64[::-1]) / 100.0
    return np.asarray(np.interp(np.asarray(level_dbm, dtype=np.float64), x, y), dtype=np.float64)
