"""Schedule-driven simulated sessions, vectorised: whole sessions as numpy arrays, no firmware.

A *schedule* (:mod:`uwbcal.schedules`, re-exported here) says what the stations were asked to
do; :func:`run_triplets` / :func:`run_ranges` let a :class:`World` play it and return the
record columns (``columns.TRIPLET`` / ``columns.RANGE`` names) and the truth
(``columns.TRIPLET_TRUTH`` / ``columns.RANGE_TRUTH``). :func:`simulate_session` writes a
session file (what `uwbcal simulate` runs).
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from uwbcal import __version__, dw1000
from uwbcal.physics.scenario import Scenario
from uwbcal.physics.world import World, reception_gaps
from uwbcal.schedules import (
    DEFAULT_GAIN,
    PAPER_DISTANCES_M,
    RangeSchedule,
    TripletSchedule,
    drift_schedule,
    plan_schedule,
    power_schedule,
    schedule_from_records,
    twr_schedule,
)
from uwbcal.sessions import columns

__all__ = [
    "DEFAULT_GAIN", "PAPER_DISTANCES_M", "RangeSchedule", "TripletSchedule", "drift_schedule",
    "plan_schedule", "power_schedule", "run_ranges", "run_schedule", "run_triplets",
    "schedule_from_records", "session_meta", "simulate_session", "triplet_gaps", "twr_schedule",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Columns = dict[str, np.ndarray]  # type: ignore[type-arg]

TU = dw1000.TIME_UNIT_S


# --- running -------------------------------------------------------------------------------

#: Rows simulated per vectorised chunk (keeps the working set in cache).
CHUNK_ROWS = 16384


def _groups(a: IntArray, b: IntArray) -> list[tuple[int, int, IntArray]]:
    if not a.size:
        return []
    if np.all(a == a[0]) and np.all(b == b[0]):
        return [(int(a[0]), int(b[0]), np.arange(a.size))]
    key = a * (1 << 32) + b
    uniq, inv = np.unique(key, return_inverse=True)
    return [(int(u >> 32), int(u & 0xFFFFFFFF), np.flatnonzero(inv == i)) for i, u in enumerate(uniq)]


def _chunks(idx: IntArray, size: int) -> list[IntArray | slice]:
    """Pieces of an index array; contiguous pieces as slices (cheaper to scatter into)."""
    out: list[IntArray | slice] = []
    for start in range(0, idx.size, size):
        part = idx[start : start + size]
        if part.size and int(part[-1]) - int(part[0]) + 1 == part.size:
            out.append(slice(int(part[0]), int(part[-1]) + 1))
        else:
            out.append(part)
    return out


def _gaps_sorted(st: IntArray, t: FloatArray) -> FloatArray:
    """Gaps between receptions at the same station (inf for the first); fast when each
    station's times are already in order."""
    if st.size and np.all(st == st[0]):
        if np.all(t[1:] >= t[:-1]):
            g = np.empty_like(t)
            g[0] = np.inf
            np.subtract(t[1:], t[:-1], out=g[1:])
            return g
    return reception_gaps(st, t)


def triplet_gaps(schedule: TripletSchedule) -> FloatArray:
    """Interference gaps (s) of P1, P2, P3 of every row, shape (n, 3), from the nominal times
    t_s, t_s + spacing, t_s + spacing + spacing23 (only microseconds matter) over all of a
    receiver's rows."""
    sp, sp23 = schedule.spacing_s, schedule.spacing23_s
    # t + 2 sp where the spacings are equal: the same floats as a one-spacing schedule always had
    t3 = schedule.t_s + np.where(sp23 == sp, 2.0 * sp, sp + sp23)
    t = np.stack([schedule.t_s, schedule.t_s + sp, t3], axis=1)
    st = np.repeat(schedule.rx_station, 3)
    return _gaps_sorted(st, t.ravel()).reshape(-1, 3)


def _dist_arg(d: FloatArray) -> FloatArray | None:
    if np.all(np.isnan(d)):
        return None
    return d


def run_triplets(
    world: World, schedule: TripletSchedule, chunk_rows: int = CHUNK_ROWS
) -> tuple[Columns, Columns]:
    """Play a triplet schedule: (records by columns.TRIPLET name, truth by columns.TRIPLET_TRUTH).

    Vectorised per (tx, rx) pair in chunks of ``chunk_rows``; interference gaps come from
    :func:`triplet_gaps`. Timestamps are int64 device units (wrapped if timestamp_wrap is on),
    registers int64, reals float64. Reproducible for a world seed and chunk size.
    """
    n = len(schedule)
    rec: Columns = {
        name: np.zeros(n, np.int64) if typ == "INTEGER" else np.zeros(n)
        for name, typ, _, _ in columns.TRIPLET
    }
    truth: Columns = {
        name: np.zeros(n, np.int64) if typ == "INTEGER" else np.zeros(n)
        for name, typ, _, _ in columns.TRIPLET_TRUTH
    }
    gaps = triplet_gaps(schedule)
    for tx, rx, idx in _groups(schedule.tx_station, schedule.rx_station):
        nominal = world.nominal_distance_m(tx, rx)
        for sel in _chunks(idx, chunk_rows):
            t0 = schedule.t_s[sel]
            m = t0.size
            dx1 = np.floor(world.local_units(tx, t0)).astype(np.int64)
            sp = np.rint(schedule.spacing_s[sel] * (1.0 / TU)).astype(np.int64)
            sp23 = np.rint(schedule.spacing23_s[sel] * (1.0 / TU)).astype(np.int64)
            dx = np.concatenate([dx1, dx1 + sp, dx1 + sp + sp23])
            txb = world.delayed_tx(tx, dx)
            g13 = schedule.gain13[sel]
            gains = np.concatenate([g13, schedule.gain2[sel], g13])
            d = schedule.distance_m[sel]
            dist3 = None
            if _dist_arg(d) is not None:
                dd = np.where(np.isnan(d), nominal, d)
                dist3 = np.concatenate([dd, dd, dd])
            g = gaps[sel]
            gap3 = np.concatenate([g[:, 0], g[:, 1], g[:, 2]])
            rxb = world.receive(tx, rx, txb.t_true_s, gains, dist3, gap3, tx_offset_ppm=txb.offset_ppm)
            for k in range(3):
                part = slice(k * m, (k + 1) * m)
                rec[f"tx{k + 1}"][sel] = txb.stamp[part]
                rec[f"rx{k + 1}"][sel] = rxb.stamp[part]
                for reg, arr in rxb.regs.items():
                    rec[f"{reg}{k + 1}"][sel] = arr[part]
                truth[f"rx_dbm{k + 1}"][sel] = rxb.rx_dbm[part]
                truth[f"bias_s{k + 1}"][sel] = rxb.bias_s[part]
            rec["temp_c"][sel] = _temp_reading(world, rxb.temp_c[:m])
            rec["distance_m"][sel] = rxb.distance_m[:m]
            truth["offset_ppm"][sel] = rxb.offset_ppm[:m]
    for name in ("seq", "step", "tx_station", "rx_station", "t_s", "spacing_s", "gain13", "gain2"):
        rec[name] = np.asarray(getattr(schedule, name)).copy()
    truth["seq"] = schedule.seq.copy()
    return rec, truth


def _temp_reading(world: World, temp_c: FloatArray) -> FloatArray:
    t = world.scenario.effects["temperature"]
    sigma = t.values()["sensor_noise_c"]
    if t.enabled and sigma:
        return np.asarray(temp_c + world.rng.standard_normal(temp_c.shape) * sigma)
    return temp_c.copy()


def run_ranges(world: World, schedule: RangeSchedule) -> tuple[Columns, Columns]:
    """Play a TWR schedule: (records by columns.RANGE name, truth by columns.RANGE_TRUTH).

    Method "paper" (three messages; single- and double-sided TWR use the same timestamps).
    ``range_station_m`` is NaN (no on-station table in simulation).
    """
    n = len(schedule)
    rec: Columns = {}
    truth: Columns = {}
    for name, typ, _, _ in columns.RANGE:
        rec[name] = (
            np.zeros(n, np.int64)
            if typ == "INTEGER"
            else np.full(n, "paper", dtype=object)
            if typ == "TEXT"
            else np.zeros(n)
        )
    for name, typ, _, _ in columns.RANGE_TRUTH:
        truth[name] = np.zeros(n, np.int64) if typ == "INTEGER" else np.zeros(n)
    # nominal arrival times for the interference gaps (only microsecond precision matters)
    st = np.concatenate([schedule.tag_station, schedule.ref_station, schedule.tag_station])
    tt = np.concatenate(
        [schedule.t_s, schedule.t_s + schedule.reply_s, schedule.t_s + schedule.reply_s + schedule.reply2_s]
    )
    gaps = reception_gaps(st, tt)
    for ref, tag, idx in _groups(schedule.ref_station, schedule.tag_station):
        m = idx.size
        g1, g2, g3 = gaps[idx], gaps[n + idx], gaps[2 * n + idx]
        d = schedule.distance_m[idx]
        dist = None if _dist_arg(d) is None else np.where(np.isnan(d), world.nominal_distance_m(ref, tag), d)
        gain = schedule.gain[idx]
        dx1 = np.floor(world.local_units(ref, schedule.t_s[idx])).astype(np.int64)
        m1 = world.delayed_tx(ref, dx1)
        r1 = world.receive(ref, tag, m1.t_true_s, gain, dist, g1, tx_offset_ppm=m1.offset_ppm)
        dx2 = r1.stamp_unwrapped + np.rint(schedule.reply_s[idx] / TU).astype(np.int64)
        m2 = world.delayed_tx(tag, dx2)
        r2 = world.receive(tag, ref, m2.t_true_s, gain, dist, g2, tx_offset_ppm=m2.offset_ppm)
        dx3 = r2.stamp_unwrapped + np.rint(schedule.reply2_s[idx] / TU).astype(np.int64)
        m3 = world.delayed_tx(ref, dx3)
        r3 = world.receive(ref, tag, m3.t_true_s, gain, dist, g3, tx_offset_ppm=m3.offset_ppm)
        rec["t1r"][idx], rec["t1t"][idx] = m1.stamp, r1.stamp
        rec["t2t"][idx], rec["t2r"][idx] = m2.stamp, r2.stamp
        rec["t3r"][idx], rec["t3t"][idx] = m3.stamp, r3.stamp
        for reg in r1.regs:
            rec[f"{reg}_t1"][idx] = r1.regs[reg]
            rec[f"{reg}_r2"][idx] = r2.regs[reg]
            rec[f"{reg}_t3"][idx] = r3.regs[reg]
        rec["temp_c"][idx] = _temp_reading(world, m1.temp_c)
        rec["distance_m"][idx] = r1.distance_m
        truth["distance_m"][idx] = r1.distance_m
        truth["tof_s"][idx] = r1.tof_s
        truth["rx_dbm_t1"][idx] = r1.rx_dbm
        truth["rx_dbm_r2"][idx] = r2.rx_dbm
        del m
    rec["seq"] = schedule.seq.copy()
    rec["ref_station"] = schedule.ref_station.copy()
    rec["tag_station"] = schedule.tag_station.copy()
    rec["t_s"] = schedule.t_s.copy()
    rec["gain"] = schedule.gain.copy()
    rec["range_station_m"] = np.full(n, np.nan)
    truth["seq"] = schedule.seq.copy()
    return rec, truth


def run_schedule(world: World, schedule: TripletSchedule | RangeSchedule) -> tuple[Columns, Columns]:
    """:func:`run_triplets` or :func:`run_ranges`, whichever the schedule is for."""
    if isinstance(schedule, TripletSchedule):
        return run_triplets(world, schedule)
    return run_ranges(world, schedule)


# --- sessions ------------------------------------------------------------------------------


def session_meta(
    scenario: Scenario, seed: int, experiment: str, settings: Mapping[str, Any]
) -> dict[str, Any]:
    """The meta entries of a simulated session (docs/SESSIONS.md)."""
    return {
        "kind": "simulated",
        "source": f"uwbcal simulate ({scenario.name})",
        "experiment": experiment,
        "scenario": scenario.to_toml(),
        "scenario_name": scenario.name,
        "seed": int(seed),
        "station_uids": {str(s.id): s.uid for s in scenario.stations},
        "firmware_version": None,
        "protocol_version": None,
        "uwbcal_version": __version__,
        "radio": {
            "channel": scenario.radio.channel,
            "prf_mhz": scenario.radio.prf_mhz,
            "preamble_length": scenario.radio.preamble_length,
            "data_rate_kbps": scenario.radio.data_rate_kbps,
        },
        "settings": dict(settings),
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }


def simulate_session(
    scenario: Scenario,
    schedule: TripletSchedule | RangeSchedule,
    out: str | Path,
    seed: int | None = None,
    experiment: str = "",
    settings: Mapping[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Simulate a schedule and write it as a session file (records and truth); returns the path."""
    from uwbcal.sessions.store import Session

    world = World(scenario, seed)
    rec, truth = run_schedule(world, schedule)
    kind = "triplets" if isinstance(schedule, TripletSchedule) else "ranges"
    meta = session_meta(scenario, world.seed, experiment or kind, settings or {})
    with Session.create(out, meta, overwrite=overwrite) as s:
        for st in scenario.stations:
            s.add_station(st.id, st.uid, st.name, {"role": "simulated"})
        s.append(kind, rec)
        s.append(f"truth_{kind}", truth)
    return Path(out)
