"""Command-line glue shared by the session commands (drift, calibrate, range).

Options every session command takes, port resolution for ``--resume``, opening and preparing
the stations, the session file, and the printed summary. Data flows one way: commands ->
sessions (plan.py, runner.py, the library) -> device -> link. Not a subcommand: the CLI skips
modules whose name starts with ``_``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

from uwbcal.device import Device
from uwbcal.errors import DeviceTimeout, LinkError, SessionError, UwbcalError
from uwbcal.sessions.runner import (
    DEFAULT_ANTD,
    PAPER_RADIO,
    SESSION_RETRIES,
    RunError,
    RunResult,
    StationInfo,
    check_same_stations,
    open_or_create,
    prepare,
)
from uwbcal.sessions.store import Session


def add_common_args(p: Any) -> None:
    """Options every session command takes."""
    p.add_argument("--out", type=Path, metavar="S.db", help="new session file")
    p.add_argument("--resume", type=Path, metavar="S.db", help="continue a broken session")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    p.add_argument("--json", action="store_true", help="print the analysis as one JSON object")
    p.add_argument("--plots", type=Path, metavar="DIR", help="write the analysis' PNG figures into DIR")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-analysis", action="store_true", help="record only")
    p.add_argument("--tx-antd", type=int, default=DEFAULT_ANTD, help="TX antenna delay, device units")
    p.add_argument("--rx-antd", type=int, default=DEFAULT_ANTD, help="RX antenna delay, device units")
    p.add_argument("--timeout", type=float, default=2.0, help="link timeout per request, s")
    p.add_argument("--retries", type=int, default=SESSION_RETRIES,
                   help="resends of an unanswered request before the session gives up (a noisy link "
                        "needs a few; every request runs at most once on the station)")


def open_devices(ports: list[str], timeout: float, retries: int = SESSION_RETRIES) -> list[Device]:
    """Open the ports (LinkError names the one that fails)."""
    if retries < 0:
        raise RunError(f"--retries {retries}: give 0 or more")
    devs: list[Device] = []
    try:
        for port in ports:
            devs.append(Device.open(port, timeout=timeout, retries=retries))
    except BaseException:
        for d in devs:
            d.close()
        raise
    return devs


def finish(args: Any, session: Session, kind: str, result: RunResult, power: list[Path] | None = None,
           station_tables: dict[int, bytes] | None = None) -> int:
    """Print the run summary and the corrections engineer's analysis (report or JSON).

    ``station_tables`` (station id -> table bytes pulled from it) give the analysis the curves
    the stations themselves corrected with, where ``power`` names none for that station, so a
    station ranging outside its own table's swept levels is warned about too."""
    import json

    from uwbcal.commands import analyze as an

    out: dict[str, Any] = {"run": {"records": result.records, "expected": result.expected,
                                   "wall_s": round(result.wall_s, 3), "complete": result.complete,
                                   "losses": result.losses, "counters": result.counters}}
    text = [f"session {session.path}: {result.records}/{result.expected} records, "
            f"{result.losses['n_missing']} missing, {result.losses['lost_frames']} stream frames lost "
            f"({result.losses.get('fetched', 0)} records fetched back, {result.losses.get('remeasured', 0)} "
            f"re-measured), {result.losses['duplicates']} duplicates dropped, {result.wall_s:.1f} s"]
    failed: UwbcalError | None = None
    st = session.meta.get("settings") or {}
    if kind == "twr" and st.get("distance_m") is None and not st.get("distances_m"):
        text.append("no --distance given: ranges recorded without an error analysis (it needs the true "
                    "distance; Z comes from it)")
        out["analysis_skipped"] = "no distance"
    elif not args.no_analysis and result.records:
        if args.plots is not None:
            args.plots.mkdir(parents=True, exist_ok=True)
        try:
            if kind == "drift":
                res = an.analyze_drift_session(session, args.plots)
            elif kind == "power":
                res = an.analyze_power_session(session, args.plots, -85.0, True, 3.0)
            else:
                res = an.analyze_twr_session(session, args.plots, power or [], None, tables=station_tables)
            res = an._finite(res)
            session.set_result(f"analyze_{kind}", res)
            out["analysis"] = res
            text.append(an.report(kind, res))
            if res.get("warnings"):
                res["warnings"] = [_with_ports(w, st) for w in res["warnings"]]
                session.set_result("warnings", res["warnings"])
                out["warnings"] = res["warnings"]
            out["next"] = next_step(kind, session.path, res)
            text.append(out["next"])
        except UwbcalError as exc:
            failed = exc
            out["analysis_error"] = str(exc)
            out["code"] = exc.exit_code
            text.append(f"analysis failed: {exc}")
    if args.json:
        print(json.dumps(out))
    else:
        print("\n".join(text))
    if not result.complete:
        return 10
    return 0 if failed is None else failed.exit_code


def pull_tables(devs: Sequence[Device], ids: Sequence[int]) -> dict[int, bytes]:
    """The active calibration table of each station that has one (station id -> bytes)."""
    from uwbcal import tables
    from uwbcal.errors import ProtocolError

    out: dict[int, bytes] = {}
    for dev, sid in zip(devs, ids, strict=True):
        try:
            out[sid] = tables.pull(dev.client)
        except ProtocolError:
            continue            # no table on this station (ERROR not_found)
    return out


def _with_ports(warning: str, st: dict[str, Any]) -> str:
    """A warning's re-calibration hint with the session's own ports (``--tx PEER --rx STATIONn``)."""
    ports = {st.get("ref_station"): st.get("ref_port"), st.get("tag_station"): st.get("tag_port")}
    for sid, port in ports.items():
        peer = next((p for s, p in ports.items() if s != sid), None)
        if sid is not None and port and peer:
            warning = warning.replace(f"--tx PEER --rx STATION{sid}", f"--tx {peer} --rx {port}")
    return warning


def next_step(kind: str, path: Path, res: dict[str, Any]) -> str:
    """The command a user runs after a drift, power or twr session (a one-line hint)."""
    if kind == "power":
        rx = sorted({int(c["rx_station"]) for c in res.get("calibrations", [])})
        out = f"station{rx[0]}.json" if len(rx) == 1 else "tables/"
        return f"next: uwbcal table build {path} --out {out}   (Z from a range session later: --z-m)"
    if kind == "twr":
        m = res.get("methods", {})
        best = m.get("paper") or m.get("paper_no_power") or {}
        z = best.get("z_m")
        if z is None:
            return "next: range at a known --distance to learn Z"
        return (f"next: put Z into the tables: uwbcal table build CAL.db --out T.json --z-m {z:+.4f} "
                f"(Z of the paper's method here, from {res.get('z_distance_m')} m), then table push")
    return f"next: uwbcal calibrate ... (a power sweep), or uwbcal analyze drift {path} --plots DIR"


def resolve_ports(args: argparse.Namespace, command: str, roles: Sequence[str]) -> None:
    """Check and complete the port options ``--<role>`` of a session command (in place).

    A new session needs every port (RunError otherwise). ``--resume S.db`` needs a session
    recorded by ``command`` (SessionError otherwise); a port not given takes the one stored in
    the session's settings (``<role>_port``).
    """
    if args.resume is None and any(getattr(args, role) is None for role in roles):
        raise RunError("give " + " and ".join(f"--{role} PORT" for role in roles))
    if args.resume is not None:
        with Session.open(args.resume, readonly=True) as s0:
            st0 = s0.meta.get("settings") or {}
        if st0.get("command") != command:
            raise SessionError(f"{args.resume}: not a {command} session ({st0.get('command')!r})")
        for role in roles:
            stored = st0.get(f"{role}_port")
            if getattr(args, role) is None and stored is None:
                raise SessionError(f"{args.resume}: its settings name no {role} port; give --{role} PORT")
            setattr(args, role, getattr(args, role) or stored)


#: What :func:`command_stations` yields: devices, radio settings, what each station said.
CommandStations = tuple[list[Device], dict[str, int], list[StationInfo]]


@contextmanager
def command_stations(args: argparse.Namespace, command: str,
                     roles: Sequence[str]) -> Iterator[CommandStations]:
    """The stations of a session command, open and prepared: resolves the ports
    (:func:`resolve_ports`), opens them, stops and configures each (the paper's radio, the
    antenna delays of ``args``). Yields (devices, radio settings, station infos) in ``roles``
    order; closes the devices on exit."""
    resolve_ports(args, command, roles)
    devs = open_devices([getattr(args, role) for role in roles], args.timeout,
                        getattr(args, "retries", SESSION_RETRIES))
    with ExitStack() as stack:
        for d in devs:
            stack.enter_context(d)
        radio = dict(PAPER_RADIO)
        infos = [prepare(d, radio, args.tx_antd, args.rx_antd) for d in devs]
        yield devs, radio, infos


@contextmanager
def command_session(args: argparse.Namespace, stations: list[StationInfo],
                    meta: Callable[[], dict[str, Any]]) -> Iterator[tuple[Session, dict[str, Any]]]:
    """The session of a session command: new at ``--out`` (``meta()`` gives its meta) or the
    one to ``--resume``, checked to belong to ``stations`` (SessionError otherwise), with the
    stations added. Yields (session, its settings); closes the session on exit."""
    session, st = open_or_create(args.out, args.resume, meta, args.force)
    with session:
        check_same_stations(session, stations)
        for info in stations:
            session.add_station(info.station_id, info.uid, info.board, {"port": info.port,
                                                                        "firmware": info.firmware})
        try:
            yield session, st
        except (LinkError, DeviceTimeout) as exc:
            raise type(exc)(f"{exc}; {resume_hint(session, st)}") from None


def run_triplet_command(args: argparse.Namespace, tx: Device, rx: Device, stations: list[StationInfo],
                        meta: Callable[[], dict[str, Any]], run_name: str, kind: str) -> int:
    """The body of a two-station triplet command (drift, calibrate): its session (new or
    resumed, :func:`command_session`), the plan of its settings run from ``tx`` to ``rx`` from
    where the session stands, the run recorded as ``run_name``, then :func:`finish` as ``kind``."""
    from uwbcal.sessions import plan as pl
    from uwbcal.sessions import runner as r

    with command_session(args, stations, meta) as (session, st):
        res = r.run_triplets(tx, rx, session, pl.TripletPlan.from_settings(st), stations[0].station_id,
                             stations[1].station_id, st.get("distance_m"), progress=not args.no_progress)
        r.record_run(session, run_name, res)
        return finish(args, session, kind, res)


def resume_hint(session: Session, settings: dict[str, Any]) -> str:
    """What to do after a link loss: the session keeps what arrived; --resume fills the rest."""
    n = sum(session.count(t) for t in ("triplets", "ranges"))
    cmd = settings.get("command") or "<command>"
    return (f"{session.path} keeps the {n} records received: continue it with "
            f"`uwbcal {cmd} --resume {session.path}` once the station answers again (with its port "
            f"option if the port changed)")
