"""`uwbcal antenna asil RUN [--check OTHER_RUN]` or `uwbcal antenna sessions R.db... [--power
P.db...] [--check S.db...]`: per-station antenna delays from three or more stations at
tape-measured distances (uwbcal.corrections.antenna), with uncertainties.

sessions: range sessions (`uwbcal range ... --distance D`, one per pair or several pairs) whose
exchanges are corrected with the stations' power curves (--power: calibrate sessions or tables,
the paper's E1/E2) before the delays are solved (then --power-model none is right: the curves
took the power dependence out).

RUN is a run directory of the asil-lab dataset (four nodes, all six pair distances in its
parameters.yaml): every ordered node pair's three-message exchanges are taken from the logged
timestamps (drift-corrected TWR, the paper's equation without power terms), the per-station
delays are solved by robust least squares and, with --check, used to predict the other run's
six distances. The report gives each pair's error against two baselines: Decawave's default
delays (16436 device units for TX and RX: "uncalibrated") and one constant Z for all pairs
from RUN. --power aps011 (default) adds the generic RX-power bias curve with a fitted RX level
at 1 m, because these logs carry no RX levels (see the module docs for what that cannot see).
--out writes the solution (JSON) for `uwbcal table build --antenna`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``antenna`` command."""
    p = subparsers.add_parser("antenna", help="per-station antenna delays from 3+ stations at known distance",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("source", choices=("asil", "sessions"),
                   help="where the ranges come from: an asil dataset run, or range session files")
    p.add_argument("run", type=Path, nargs="+", help="run directory (asil) or range sessions to calibrate on")
    p.add_argument("--check", type=Path, action="append", default=[], metavar="RUN2",
                   help="another run / range session (other geometry) whose distances the solution predicts")
    p.add_argument("--try", dest="try_name", default=None,
                   help="asil: try of the run (default: the only one)")
    p.add_argument("--power", type=Path, action="append", default=[], metavar="P.db|T.json",
                   help="sessions: power curves that correct the ranges first (repeatable)")
    p.add_argument("--power-model", choices=("aps011", "none"), default=None,
                   help="power-bias term of the model (default: aps011 for asil, none for sessions)")
    p.add_argument("--out", type=Path, default=None, metavar="ANTD.json", help="write the solution")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def asil_pairs(run_dir: Path, try_name: str | None) -> list[Any]:
    """PairRanges of every ordered node pair of an asil run (ranges in m, delays not removed)."""
    import numpy as np

    from uwbcal.corrections import antenna, twr
    from uwbcal.errors import SessionError
    from uwbcal.importers.asil_twr import run_exchanges

    out = []
    for p in run_exchanges(run_dir, try_name):
        if p.distance_m is None:
            raise SessionError(f"{run_dir}: parameters.yaml gives no distance for nodes {p.ref} and {p.tag}")
        r = twr.units_to_range_m(twr.paper_tof_units(p.t1r, p.t1t, p.t2t, p.t2r, p.t3r, p.t3t))
        out.append(antenna.PairRanges(p.ref, p.tag, float(p.distance_m), np.asarray(r)))
    return out


def session_pairs(paths: list[Path], power: list[Path]) -> list[Any]:
    """PairRanges of range sessions at declared distances: the paper's TWR with the curves of
    ``power`` (drift + E1/E2) when given, else drift only; ranges in m, delays not removed."""
    import numpy as np

    from uwbcal.commands.analyze import power_sources
    from uwbcal.corrections import analysis, antenna
    from uwbcal.errors import SessionError
    from uwbcal.sessions.store import Session

    curves = power_sources(power)[0] if power else {}
    out = []
    for path in paths:
        if not path.exists():
            raise SessionError(f"{path}: no such session file")
        with Session.open(path, readonly=True) as s:
            rg = dict(s.read("ranges"))
        ranges = analysis.twr_ranges_m(rg, curves or None)
        r = ranges.get("paper") if curves else ranges.get("paper_no_power")
        if r is None:
            raise SessionError(f"{path}: no three-message exchanges (or no curve for a station of a pair)")
        dist, ref, tag = (analysis.column(rg, c) for c in ("distance_m", "ref_station", "tag_station"))
        if dist is None or ref is None or tag is None:
            raise SessionError(f"{path}: the ranges carry no declared distance (range --distance D)")
        for a, b in analysis.pairs(rg, "ref_station", "tag_station"):
            for d in np.unique(dist[(ref == a) & (tag == b) & np.isfinite(dist)]):
                sel = (ref == a) & (tag == b) & (dist == d) & np.isfinite(r)
                out.append(antenna.PairRanges(int(a), int(b), float(d), np.asarray(r[sel])))
    return out


def compare(cal: list[Any], test: list[Any], power: str, base_delay_m: float | None = None) -> dict[str, Any]:
    """Solve on ``cal``; per-pair errors on ``test`` (m) for uncalibrated, one Z and calibrated.
    Uncalibrated: Decawave's default delays (``base_delay_m`` None, for logs taken with delays 0)
    or ``base_delay_m`` per station (0 for sessions whose stations had the defaults programmed)."""
    import numpy as np

    from uwbcal.corrections import antenna

    sol = antenna.solve(cal, power)
    base = antenna.default_solution(sol.stations, base_delay_m)
    z = float(np.mean(list(antenna.prediction_errors(base, cal).values())))
    errs = {"uncalibrated": antenna.prediction_errors(base, test),
            "one_z": {k: v - z for k, v in antenna.prediction_errors(base, test).items()},
            "calibrated": antenna.prediction_errors(sol, test)}
    mae = {k: float(np.mean(np.abs(list(v.values())))) for k, v in errs.items()}
    return {"solution": sol.to_dict(), "z_m": z, "errors_m": errs, "mae_m": mae,
            "mae_cut": 1.0 - mae["calibrated"] / mae["uncalibrated"]}


def run(args: argparse.Namespace) -> int:
    """Solve, optionally check on another run, report."""
    from uwbcal.corrections import antenna
    from uwbcal.errors import SessionError

    if args.source == "asil":
        if len(args.run) != 1 or len(args.check) > 1:
            raise SessionError("asil: give one run directory (and at most one --check run)")
        model = args.power_model or "aps011"
        cal = asil_pairs(args.run[0], args.try_name)
        test = asil_pairs(args.check[0], None) if args.check else None
    else:
        model = args.power_model or "none"
        cal = session_pairs(args.run, args.power)
        test = session_pairs(args.check, args.power) if args.check else None
    name = ", ".join(str(r) for r in args.run)
    try:
        sol = antenna.solve(cal, model)
    except ValueError as exc:
        raise SessionError(f"{name}: {exc}") from None
    out: dict[str, Any] = {"run": name, "solution": sol.to_dict()}
    lines = [f"{name}: {len(sol.stations)} stations, power term {sol.power}, {sol.dof} dof"]
    for s in sol.stations:
        lines.append(f"  station {s}: delay {sol.delay_m[s] * 100:9.2f} +- {sol.delay_sigma_m[s] * 100:.2f} "
                     f"cm of range -> TX_ANTD = LDE_RXANTD = {sol.antd_units(s)} units")
    if sol.l1_dbm is not None:
        lines.append(f"  RX level at 1 m (fitted): {sol.l1_dbm:.1f} +- {sol.l1_sigma_db or 0.0:.1f} dBm")
    if test is not None:
        cmp = compare(cal, test, model, None if args.source == "asil" else 0.0)
        checked = ", ".join(str(c) for c in args.check)
        out["check"] = {"run": checked, **{k: v for k, v in cmp.items() if k != "solution"}}
        lines.append(f"prediction of {checked} (range minus tape distance, cm):")
        lines.append(f"  {'pair':6s} {'uncalibrated':>13s} {'one Z':>8s} {'calibrated':>11s}")
        e = cmp["errors_m"]
        for k in e["calibrated"]:
            lines.append(f"  {k:6s} {e['uncalibrated'][k] * 100:13.1f} {e['one_z'][k] * 100:8.1f} "
                         f"{e['calibrated'][k] * 100:11.1f}")
        m = cmp["mae_m"]
        lines.append(f"  {'MAE':6s} {m['uncalibrated'] * 100:13.1f} {m['one_z'] * 100:8.1f} "
                     f"{m['calibrated'] * 100:11.1f}   (calibrated cuts the uncalibrated MAE by "
                     f"{cmp['mae_cut'] * 100:.0f} %)")
    if args.out is not None:
        args.out.write_text(json.dumps(sol.to_dict(), indent=1) + "\n")
        lines.append(f"wrote {args.out}; next: uwbcal table build CAL.db --out T.json --antenna {args.out}")
    print(json.dumps(out) if args.json else "\n".join(lines))
    return 0
