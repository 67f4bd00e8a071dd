"""`uwbcal analyze drift|power|twr S.db`: the paper's corrections and the baselines on a session.

Works on any session in the schema (simulated, firmware-in-the-loop, imported real data); it
reads only the record tables, never the simulation truth. Results are stored in the session
(``analyze_drift``, ``analyze_power``, ``analyze_twr``) and printed as a short report, or as one
JSON object with ``--json``. ``--plots DIR`` writes PNG figures.
"""

from __future__ import annotations

import argparse
import json
import math
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from uwbcal.dw1000 import C_LIGHT
from uwbcal.errors import SessionError


def register(subparsers: Any) -> None:
    """Add the ``analyze`` command."""
    p = subparsers.add_parser("analyze", help="run the corrections and baselines on a session file",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("kind", choices=("drift", "power", "twr"), help="which analysis")
    p.add_argument("session", type=Path, nargs="+",
                   help="session file (SQLite); twr takes several (e.g. one per distance), analysed as one")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plots", type=Path, metavar="DIR", help="write PNG figures into DIR")
    p.add_argument("--threshold", type=float, default=-85.0, metavar="DBM",
                   help="power: measured level below which the estimate is taken as right (default -85)")
    p.add_argument("--fixed-slope", action="store_true",
                   help="power: fit only the offset of measured vs real (slope 1)")
    p.add_argument("--real-method", choices=("auto", "nominal", "stitch"), default="auto",
                   help="power: real power from a line through the nominal steps (the paper), from "
                        "stitched coarse-gain segments, or auto (stitch when the sweep allows)")
    p.add_argument("--coarse-step-db", type=float, default=3.0, help="power: nominal coarse gain step, dB")
    p.add_argument("--power", type=Path, action="append", default=[], metavar="P.db|T.json",
                   help="twr: power-sweep session(s) or table file(s) giving the curves of their RX stations "
                        "(repeatable); a stored analyze_power result is used when present")
    p.add_argument("--z-distance", type=float, default=None, metavar="M",
                   help="twr: the known distance used for Z (default: the median distance)")
    p.add_argument("--level-window", type=int, default=1, metavar="N",
                   help="twr: average each station's measured RX level over N exchanges before looking "
                        "up E1/E2 and APS011 (default 1: every frame's own level)")
    p.add_argument("--no-store", action="store_true", help="do not store the result in the session")
    p.set_defaults(func=run)


def _finite(x: Any) -> Any:
    """JSON-safe copy: NaN/inf -> None, numpy scalars -> Python."""
    if isinstance(x, dict):
        return {str(k): _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def run(args: argparse.Namespace) -> int:
    """Run one analysis; print a report or JSON; store the result unless --no-store."""
    from uwbcal.sessions.store import Session

    paths: list[Path] = args.session
    if len(paths) > 1 and args.kind != "twr":
        raise SessionError(f"analyze {args.kind} takes one session (twr takes several)")
    for path in paths:
        if not path.exists():
            raise SessionError(f"{path}: no such session file")
    store = not args.no_store and len(paths) == 1
    # Read-only until the result is ready and the file has passed integrity_check: a damaged
    # file is never opened for writing, so nothing is written into it, not even a journal mode.
    with ExitStack() as stack:
        ss = [stack.enter_context(Session.open(p, readonly=True)) for p in paths]
        s = ss[0]
        if args.kind == "drift":
            result = analyze_drift_session(s, args.plots)
        elif args.kind == "power":
            result = analyze_power_session(s, args.plots, args.threshold, not args.fixed_slope,
                                           args.coarse_step_db, args.real_method)
        else:
            result = analyze_twr_session(ss, args.plots, args.power, args.z_distance, args.level_window)
        result = _finite(result)
        if store:
            s.verify(full=True)
    if store:
        with Session.open(paths[0]) as s:
            s.set_result(f"analyze_{args.kind}", result)
    if args.json:
        print(json.dumps(result, sort_keys=False))
    else:
        print(report(args.kind, result))
    return 0


# --- the three analyses on an open session -----------------------------------------------

def _triplets(s: Any) -> dict[str, Any]:
    tr = s.read("triplets")
    from uwbcal.corrections.analysis import n_rows

    if n_rows(tr) == 0:
        raise SessionError("the session has no triplet records")
    return dict(tr)


def analyze_drift_session(s: Any, plots: Path | None) -> dict[str, Any]:
    """Eq. 1 residual per station pair (m), with and without correction, and the integrator."""
    from uwbcal.corrections import analysis

    tr = _triplets(s)
    radio = analysis.session_radio(s.meta)
    pairs = analysis.analyze_drift_records(tr, radio.channel, radio.data_rate_kbps)
    out: dict[str, Any] = {"kind": "drift", "pairs": pairs}
    if plots is not None:
        from uwbcal import plots as pl

        files = []
        for d in pairs:
            mask = analysis._pair_mask(tr, "tx_station", "rx_station", (d["tx_station"], d["rx_station"]))
            series = analysis.drift_residual_series(analysis.subset(tr, mask))
            window = max(1, min(500, len(series["t_s"]) // 20))
            floor = d["corrected"]["std_m"] / math.sqrt(window)
            name = f"drift_{d['tx_station']}to{d['rx_station']}.png"
            files.append(str(pl.plot_drift(series, plots / name, floor, window,
                                           f"Clock drift correction, station {d['tx_station']} -> "
                                           f"{d['rx_station']}")))
        out["plots"] = files
    return out


def analyze_power_session(s: Any, plots: Path | None, threshold_dbm: float, fit_slope: bool,
                          coarse_step_db: float, method: str = "auto") -> dict[str, Any]:
    """Power self-calibration per station pair: the curve, measured vs real, per-step stats."""
    from uwbcal.corrections import analysis

    tr = _triplets(s)
    radio = analysis.session_radio(s.meta)
    opts = analysis.PowerOptions(threshold_dbm=threshold_dbm, fit_slope=fit_slope,
                                 coarse_step_db=coarse_step_db, method=method,
                                 prf_mhz=radio.prf_mhz, data_rate_kbps=radio.data_rate_kbps)
    cals = analysis.calibrate_power_records(tr, opts)
    out: dict[str, Any] = {"kind": "power", "calibrations": [
        {"tx_station": p[0], "rx_station": p[1], **c.to_dict()} for p, c in cals.items()]}
    if plots is not None:
        from uwbcal import plots as pl

        labelled = [(f"{p[0]}->{p[1]}", c) for p, c in cals.items()]
        tag = "_".join(f"{p[0]}to{p[1]}" for p in cals)       # one file per direction, never overwritten
        out["plots"] = [str(pl.plot_power(labelled, plots / f"power_curve_{tag}.png",
                                          "Power self-calibration")),
                        str(pl.plot_measured_vs_real(labelled, plots / f"measured_vs_real_{tag}.png"))]
    return out


def curves_from_sessions(paths: list[Path]) -> dict[int, Any]:
    """Power curves by RX station from power-sweep sessions (stored result, else computed)."""
    return power_sources(paths)[0]


def _sweep_distance_m(ps: Any) -> float | None:
    """TX-RX distance of a power sweep, m: its settings' ``distance_m``, else the median of the
    triplets' distance_m column (simulated and imported sessions), else None."""
    st = ps.meta.get("settings") or {}
    if st.get("distance_m") is not None:
        return float(st["distance_m"])
    d = [r[0] for r in ps.conn.execute("SELECT distance_m FROM triplets WHERE distance_m IS NOT NULL "
                                       "ORDER BY distance_m LIMIT 1000")]
    return float(np.median(d)) if d else None


def power_sources(paths: list[Path]) -> tuple[dict[int, Any], dict[int, Any]]:
    """Power curves and their validity (corrections/validity.py) by RX station, from power-sweep
    sessions (stored analyze_power result, else computed) and table files (T.json)."""
    from uwbcal import tables
    from uwbcal.corrections import analysis, validity
    from uwbcal.corrections.power import PowerCurve
    from uwbcal.sessions.store import Session

    curves: dict[int, PowerCurve] = {}
    valid: dict[int, validity.Validity] = {}
    for path in paths:
        if path.suffix == ".json":
            data = tables.load(path)
            v = tables.load_validity(path)
            c = tables.curve_of(data, None if v is None else v.get("station"))
            if c.rx_station is None:
                raise SessionError(f"{path}: the table names no station (build it with this uwbcal)")
            curves[c.rx_station] = c
            valid[c.rx_station] = validity.Validity.from_dict(v) if v else validity.of_curve(c)
            continue
        with Session.open(path, readonly=True) as ps:
            dist = _sweep_distance_m(ps)
            stored = ps.results().get("analyze_power")
            if stored:
                items = [(int(c["rx_station"]), PowerCurve.from_dict(c["curve"]), c.get("threshold_dbm"))
                         for c in stored["calibrations"]]
            else:
                items = [(rx, cal.curve, cal.threshold_dbm)
                         for (_tx, rx), cal in analysis.calibrate_power_records(_triplets(ps)).items()]
            for rx, (pc, thr) in validity.loudest_per_station(items).items():
                curves[rx] = pc
                valid[rx] = validity.of_curve(pc, thr, dist)
    return curves, valid


def analyze_twr_session(s: Any, plots: Path | None, power_paths: list[Path],
                        z_distance_m: float | None, level_window: int = 1,
                        tables: dict[int, bytes] | None = None) -> dict[str, Any]:
    """Range error per distance for each correction on/off and the baselines (needs distance_m);
    which corrections were applied to how many records, with warnings where a power curve was
    extrapolated or a declared distance disagrees with the ranges. ``s`` is one open session
    or a list of them (their range records analysed together, e.g. one session per distance).
    ``tables`` (station id -> table bytes, e.g. pulled from the stations) add the stations' own
    curves where neither ``power_paths`` nor the session give one."""
    from uwbcal.corrections import analysis, validity
    from uwbcal.corrections.power import PowerCurve

    sessions = list(s) if isinstance(s, list) else [s]
    parts = [dict(x.read("ranges")) for x in sessions]
    rg = {k: np.concatenate([np.asarray(p[k]) for p in parts]) for k in parts[0]}
    if analysis.n_rows(rg) == 0:
        raise SessionError("the session has no range records")
    curves, valid = power_sources(power_paths)
    for stored in (x.results().get("analyze_power") for x in sessions):
        if not stored:
            continue
        for c in stored["calibrations"]:
            pc = PowerCurve.from_dict(c["curve"])
            curves.setdefault(int(c["rx_station"]), pc)
            valid.setdefault(int(c["rx_station"]), validity.of_curve(pc, c.get("threshold_dbm")))
    if tables:
        from uwbcal import tables as tb

        for sid, data in tables.items():
            if sid not in curves:
                curves[sid] = tb.curve_of(data, sid)
                valid[sid] = validity.of_curve(curves[sid])
    res = analysis.analyze_twr_records(rg, curves or None, z_distance_m, level_window=level_window,
                                       validity=valid)
    out: dict[str, Any] = {"kind": "twr", "sessions": [str(x.path) for x in sessions],
                           "curves_for_stations": sorted(curves), **res}
    if plots is not None:
        from uwbcal import plots as pl

        paper = res["methods"].get("paper") or res["methods"]["paper_none"]
        floor = float(paper["mean_within_std_m"])
        out["plots"] = [str(pl.plot_twr(res, plots / "twr.png", floor))]
    return out


def _corrections_lines(c: dict[str, Any] | None) -> list[str]:
    """What the TWR analysis applied to how many records (``corrections`` of its result)."""
    if not c:
        return []
    n = c["records"]
    pw = c["power_curves"]
    lines = [f"corrections on {n} records: drift (eq. 1) {c['drift_eq1']['applied']}, power curves "
             f"{pw['applied']} (stations {pw['stations']}; {pw['outside_swept_span']} of {2 * pw['applied']} "
             f"level look-ups outside the swept span, extrapolated), APS011 {c['aps011']['applied']}"]
    for k in ("drift_eq1", "power_curves"):
        if c[k].get("why_not"):
            lines.append(f"  {k}: not on every record: {c[k]['why_not']}")
    return lines


def report(kind: str, r: dict[str, Any]) -> str:
    """A short human-readable report of one analysis result."""
    lines: list[str] = []
    if kind == "drift":
        for d in r["pairs"]:
            lines.append(f"station {d['tx_station']} -> {d['rx_station']}: {d['corrected']['n']} triplets, "
                         f"spacing {d['spacing_s'] * 1e3:.3f} ms, drift {d['drift_ppm_mean']:+.3f} ppm "
                         f"(first {d['drift_ppm_first']:+.3f}, last {d['drift_ppm_last']:+.3f})")
            for label, key in (("uncorrected C12", "uncorrected"), ("eq. 1 C'12", "corrected"),
                               ("carrier integrator", "carrier_integrator")):
                st = d.get(key)
                if st:
                    lines.append(f"  {label:20s} mean {st['mean_m']:+.3e} m  std {st['std_m']:.3e} m  "
                                 f"sem {st['sem_m']:.1e} m")
    elif kind == "power":
        for c in r["calibrations"]:
            how = ("measured = offset + slope * nominal gain" if c["method"] == "nominal"
                   else "coarse segments stitched, slope = fine-step scale")
            lines.append(f"station {c['tx_station']} -> {c['rx_station']}: real power of P1/P3 "
                         f"{c['offset_dbm']:.2f} dBm, slope {c['slope']:.3f} ({how}; fit on {c['n_fit']} "
                         f"steps below {c['threshold_dbm']} dBm)")
            lines.append("  step  gain2  nominal_dB  measured_dBm  real_dBm  error_m      sem_m     used/rec")
            for st in c["steps"]:
                lines.append(f"  {st['step']:4d}  0x{st['gain2']:02x}  {st['nominal_db']:10.2f}  "
                             f"{st['measured_dbm']:12.2f}  {st['real_dbm']:8.2f}  "
                             f"{st['error_s'] * C_LIGHT:+.4f}  {st['error_sem_s'] * C_LIGHT:.1e}  "
                             f"{st['n_used']:5d}/{st['n']}")
            used = sum(st["n_used"] for st in c["steps"])
            rec = sum(st["n"] for st in c["steps"])
            lines.append(f"  {rec - used} of {rec} triplets lie beyond 4 robust sigmas of their step's "
                         f"median (multipath, collisions): left out of the step means, kept in the session")
            lines.append(f"  {c['curve']['unknown_constant']}")
    else:
        lines.append(f"Z from {r['z_distance_m']} m; curves for stations {r['curves_for_stations']}; "
                     f"missing: {', '.join(r['missing_methods']) or 'none'}")
        lines.append(f"  {'method':20s} {'std all':>9s} {'std means':>10s} {'rms means':>10s}   Z")
        for name, m in r["methods"].items():
            lines.append(f"  {name:20s} {m['std_all_m']:9.4f} {m['std_of_means_m']:10.4f} "
                         f"{m['rms_of_means_m']:10.4f}   {m['z_m']:+.4f} m")
        lines += _corrections_lines(r.get("corrections"))
        lines += [f"WARNING: {w}" for w in r.get("warnings", [])]
    if r.get("plots"):
        lines.append("plots: " + ", ".join(r["plots"]))
    return "\n".join(lines)
