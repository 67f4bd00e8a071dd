"""Columns of a session file's record tables: the one definition that the store, the
vectorised simulator, the firmware-in-the-loop recorder, the importers and the analyses share.

Units: timestamps are DW1000 device units (1 unit = 1 / (128 * 499.2 MHz) s, about 15.65 ps),
as the chip reports them: raw 40-bit values (they wrap every 2**40 units, about 17.2 s), except
where an importer documents that its source already unwrapped them (then they may exceed 2**40;
every difference is taken modulo 2**40 anyway). Seconds are SI seconds, powers dBm, distances
metres, temperatures degrees Celsius. Register-valued columns hold the raw register field.

A record table has one row per record as it arrived (append-only). ``None``/NULL marks a value
the source did not provide.
"""

from __future__ import annotations

from typing import Final

# (name, SQL type, unit or register, description)
Column = tuple[str, str, str, str]

#: Raw RX quality registers of one received message. In the record tables each name carries
#: a suffix naming the message (``cir_pwr1`` is CIR_PWR of P1's reception).
RX_QUALITY: Final[tuple[Column, ...]] = (
    ("cir_pwr", "INTEGER", "RX_FQUAL.CIR_PWR", "channel impulse response power, 16 bits"),
    ("rxpacc", "INTEGER", "RX_FINFO.RXPACC", "preamble symbols accumulated, 12 bits, uncorrected"),
    ("rxpacc_nosat", "INTEGER", "DRX_CONF.RXPACC_NOSAT", "preamble count not saturated, 16 bits"),
    ("fp_ampl1", "INTEGER", "RX_TIME.FP_AMPL1", "first-path amplitude point 1"),
    ("fp_ampl2", "INTEGER", "RX_FQUAL.FP_AMPL2", "first-path amplitude point 2"),
    ("fp_ampl3", "INTEGER", "RX_FQUAL.FP_AMPL3", "first-path amplitude point 3"),
    ("std_noise", "INTEGER", "RX_FQUAL.STD_NOISE", "standard deviation of noise"),
    ("fp_index", "INTEGER", "RX_TIME.FP_INDEX", "first-path index, 10.6 fixed point"),
    ("car_int", "INTEGER", "DRX_CONF.DRX_CAR_INT", "carrier integrator, 21-bit signed, sign-extended"),
    ("ttcko", "INTEGER", "RX_TTCKO.RXTOFS", "RX time tracking offset, 19-bit signed, sign-extended"),
    ("ttcki", "INTEGER", "RX_TTCKI", "RX time tracking interval"),
)

#: One P1/P2/P3 triplet as received: drift runs (all gains equal) and power sweeps (P2 stepped).
TRIPLET: Final[tuple[Column, ...]] = (
    ("seq", "INTEGER", "", "triplet sequence number assigned by the TX station"),
    ("step", "INTEGER", "", "index of the gain step of a power sweep; 0 for drift runs"),
    ("tx_station", "INTEGER", "", "station id of the transmitter"),
    ("rx_station", "INTEGER", "", "station id of the receiver"),
    ("t_s", "REAL", "s", "time of P1 since the start of the session (TX station clock or truth)"),
    ("spacing_s", "REAL", "s", "nominal spacing P1->P2 and P2->P3"),
    ("gain13", "INTEGER", "TX_POWER octet", "TX gain of P1 and P3: bits 7:5 coarse, 4:0 fine"),
    ("gain2", "INTEGER", "TX_POWER octet", "TX gain of P2"),
    ("tx1", "INTEGER", "device units", "TX timestamp of P1 on the TX clock"),
    ("tx2", "INTEGER", "device units", "TX timestamp of P2 on the TX clock"),
    ("tx3", "INTEGER", "device units", "TX timestamp of P3 on the TX clock"),
    ("rx1", "INTEGER", "device units", "RX timestamp of P1 on the RX clock"),
    ("rx2", "INTEGER", "device units", "RX timestamp of P2 on the RX clock"),
    ("rx3", "INTEGER", "device units", "RX timestamp of P3 on the RX clock"),
    *[(f"{n}{k}", t, u, f"{d} (P{k})") for k in (1, 2, 3) for (n, t, u, d) in RX_QUALITY],
    ("temp_c", "REAL", "degC", "RX station temperature"),
    ("distance_m", "REAL", "m", "nominal TX-RX distance, or cable"),
)

#: One ranging exchange. Messages: M1 ref->tag (ref TX t1r, tag RX t1t), M2 tag->ref (tag TX
#: t2t, ref RX t2r), M3 ref->tag (ref TX t3r, tag RX t3t). The paper's TWR and asymmetric
#: double-sided TWR use all three; single-sided TWR uses M1 and M2 (t3r, t3t NULL).
RANGE: Final[tuple[Column, ...]] = (
    ("seq", "INTEGER", "", "exchange sequence number assigned by the reference"),
    ("method", "TEXT", "", "paper | ss | ds: which exchange the firmware ran"),
    ("ref_station", "INTEGER", "", "station id of the reference"),
    ("tag_station", "INTEGER", "", "station id of the tag"),
    ("t_s", "REAL", "s", "time of M1 since the start of the session"),
    ("distance_m", "REAL", "m", "nominal (ground-truth) distance set by the user, NULL if unknown"),
    ("t1r", "INTEGER", "device units", "M1 TX on the reference clock"),
    ("t1t", "INTEGER", "device units", "M1 RX on the tag clock"),
    ("t2t", "INTEGER", "device units", "M2 TX on the tag clock"),
    ("t2r", "INTEGER", "device units", "M2 RX on the reference clock"),
    ("t3r", "INTEGER", "device units", "M3 TX on the reference clock"),
    ("t3t", "INTEGER", "device units", "M3 RX on the tag clock"),
    ("gain", "INTEGER", "TX_POWER octet", "TX gain of every message"),
    *[(f"{n}_t1", t, u, f"{d} (M1 at the tag)") for (n, t, u, d) in RX_QUALITY],
    *[(f"{n}_r2", t, u, f"{d} (M2 at the reference)") for (n, t, u, d) in RX_QUALITY],
    *[(f"{n}_t3", t, u, f"{d} (M3 at the tag)") for (n, t, u, d) in RX_QUALITY],
    ("temp_c", "REAL", "degC", "reference temperature"),
    ("range_station_m", "REAL", "m", "range the reference computed with its own table, NULL if none"),
)

#: Simulation truth kept beside the records of a simulated session, never read by analyses
#: of the records; tests and `uwbcal paper` compare estimates against it.
TRIPLET_TRUTH: Final[tuple[Column, ...]] = (
    ("seq", "INTEGER", "", "triplet sequence number"),
    *[(f"rx_dbm{k}", "REAL", "dBm", f"true received power of P{k}") for k in (1, 2, 3)],
    *[(f"bias_s{k}", "REAL", "s", f"true power-dependent timestamp error of P{k} at the receiver")
      for k in (1, 2, 3)],
    ("offset_ppm", "REAL", "ppm", "true RX-minus-TX clock frequency offset at P1"),
)

RANGE_TRUTH: Final[tuple[Column, ...]] = (
    ("seq", "INTEGER", "", "exchange sequence number"),
    ("distance_m", "REAL", "m", "true distance"),
    ("tof_s", "REAL", "s", "true time of flight"),
    ("rx_dbm_t1", "REAL", "dBm", "true received power of M1 at the tag"),
    ("rx_dbm_r2", "REAL", "dBm", "true received power of M2 at the reference"),
)

TABLES: Final[dict[str, tuple[Column, ...]]] = {
    "triplets": TRIPLET,
    "ranges": RANGE,
    "truth_triplets": TRIPLET_TRUTH,
    "truth_ranges": RANGE_TRUTH,
}


def names(table: str) -> list[str]:
    """Column names of one record table, in order."""
    return [c[0] for c in TABLES[table]]
