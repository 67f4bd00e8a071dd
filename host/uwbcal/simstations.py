"""Simulated stations as processes: the native firmware build (``uwbcal-station``), one per
station, each serving its host link on a pty, optionally attached to a simulated radio medium.

    with SimWorld(n_stations=2, seed=1) as world:
        for st in world.stations:
            print(st.id, st.port)

Order of start: the medium first (when a :class:`MediumLauncher` is given: its socket goes to
every station as ``--medium``), then the stations; each must print its ``PTY <path>`` line and
answer PING before :meth:`SimWorld.start` returns. :meth:`SimWorld.stop` sends SIGTERM to every
process it started (SIGKILL after a grace period) and reports their exit codes.

With a medium, the medium and its stations run in lock-step: one of them works while the others
wait for it, so they share one CPU (:func:`sim_cpu`, ``$UWBCAL_SIM_CPU``). A wake-up across CPUs
costs tens of microseconds on a virtual machine, nine times per triplet: on the 2-CPU machine of
docs/SIMULATION.md, pinning took the firmware-in-the-loop calibration from 1.2 to 0.75 ms per
triplet. The host process is not pinned.
"""

from __future__ import annotations

import os
import selectors
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from uwbcal.device import Device
from uwbcal.errors import UwbcalError
from uwbcal.medium.launcher import log_tail
from uwbcal.physics.scenario import BOARDS

#: Environment variable naming the station binary.
STATION_ENV = "UWBCAL_STATION"
#: Environment variable naming the EVK1000 image the emulated stations run.
EVK1000_IMAGE_ENV = "UWBCAL_EVK1000_IMAGE"

#: Exit code of a station stopped by SIGTERM (it exits cleanly).
CLEAN_EXIT = 0


class SimError(UwbcalError):
    """A simulated station or the medium could not be started, or died."""

    exit_code = 8


class MediumLauncher(Protocol):
    """Starts the simulated radio medium; the stations then get ``--medium <socket>``."""

    def start(self, workdir: Path, seed: int, station_ids: Sequence[int]) -> str:
        """Start the medium; return the unix socket path stations connect to."""
        ...

    def stop(self) -> None:
        """Stop the medium (idempotent)."""
        ...


SIM_CPU_ENV = "UWBCAL_SIM_CPU"


def sim_cpu(env: str | None = None) -> int | None:
    """The CPU a medium and its stations are pinned to, or None for no pinning.

    ``env`` (default ``$UWBCAL_SIM_CPU``): unset or ``auto``: the highest CPU this process may
    run on, when it may run on two or more (on one there is nothing to gain); ``none``: no
    pinning; a number: that CPU, which must be one this process may run on.
    """
    value = os.environ.get(SIM_CPU_ENV, "auto") if env is None else env
    value = value.strip().lower()
    try:
        allowed = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return None
    if value in ("", "auto"):
        return allowed[-1] if len(allowed) >= 2 else None
    if value in ("none", "off", "no"):
        return None
    try:
        cpu = int(value)
    except ValueError:
        raise SimError(f"{SIM_CPU_ENV}={value!r}: expected auto, none or a CPU number") from None
    if cpu not in allowed:
        raise SimError(f"{SIM_CPU_ENV}={cpu}: this process may run on CPUs {allowed} only")
    return cpu


def _pin(pid: int, cpu: int | None) -> None:
    """Pin a process to one CPU; a failure only costs speed, so it is ignored."""
    if cpu is None:
        return
    try:
        os.sched_setaffinity(pid, {cpu})
    except (AttributeError, OSError):
        pass


def repo_root() -> Path:
    """The source tree this package runs from (host/uwbcal/.. /..)."""
    return Path(__file__).resolve().parents[2]


def station_binary(explicit: str | os.PathLike[str] | None = None) -> Path:
    """The station binary: ``explicit``, else $UWBCAL_STATION, else build/native/uwbcal-station."""
    cand = explicit or os.environ.get(STATION_ENV)
    path = Path(cand) if cand else repo_root() / "build" / "native" / "uwbcal-station"
    if not path.is_file() or not os.access(path, os.X_OK):
        hint = (
            f"${STATION_ENV} points to {path}"
            if not explicit and os.environ.get(STATION_ENV)
            else f"{path} does not exist"
        )
        raise SimError(
            f"no simulated station binary: {hint}; build it with `make native` or set {STATION_ENV}"
        )
    return path


def evk1000_image(explicit: str | os.PathLike[str] | None = None) -> Path:
    """The EVK1000 image: ``explicit``, else $UWBCAL_EVK1000_IMAGE, else the `make firmware` output."""
    cand = explicit or os.environ.get(EVK1000_IMAGE_ENV)
    path = Path(cand) if cand else repo_root() / "build" / "evk1000" / "uwbcal-evk1000.bin"
    if not path.is_file():
        raise SimError(f"no EVK1000 image: {path} does not exist; build it with `make firmware` "
                       f"or set {EVK1000_IMAGE_ENV}")
    return path


@dataclass
class Station:
    """One running simulated station."""

    id: int
    port: str
    process: subprocess.Popen[bytes]
    log_path: Path
    flash_path: Path
    returncode: int | None = None


@dataclass
class SimWorld:
    """N simulated stations (ids 1..N unless ``ids`` is given); see the module docstring."""

    n_stations: int = 1
    seed: int = 0
    binary: str | os.PathLike[str] | None = None
    workdir: Path | None = None
    medium: MediumLauncher | None = None
    scenario: Path | None = None
    ids: Sequence[int] | None = None
    start_timeout_s: float = 15.0
    extra_args: Sequence[str] = ()
    #: "native", "evk1000", or a map station id -> board (missing ids: native)
    board: str | dict[int, str] = "native"
    image: str | os.PathLike[str] | None = None
    stations: list[Station] = field(default_factory=list)
    medium_socket: str | None = None
    _own_workdir: bool = False

    def board_of(self, sid: int) -> str:
        """The board station ``sid`` runs as."""
        b = self.board if isinstance(self.board, str) else self.board.get(sid, "native")
        if b not in BOARDS:
            raise SimError(f"board {b!r} of station {sid}: expected one of {', '.join(BOARDS)}")
        return b

    def start(self) -> list[Station]:
        """Start everything and wait until each station answers PING."""
        exe = station_binary(self.binary) if self.board != "evk1000" else None
        if self.workdir is None:
            self.workdir = Path(tempfile.mkdtemp(prefix="uwbcal-sim-"))
            self._own_workdir = True
        self.workdir.mkdir(parents=True, exist_ok=True)
        ids = list(self.ids) if self.ids is not None else list(range(1, self.n_stations + 1))
        cpu: int | None = None
        if self.scenario is not None:
            # A scenario means a radio: the medium (uwbcal.medium) plays it; the stations
            # are the ones the scenario names.
            from uwbcal.medium.launcher import MediumProcess
            from uwbcal.physics.scenario import load_scenario

            sc = load_scenario(self.scenario)
            if self.board == "native":
                self.board = {st.id: st.board for st in sc.stations}
            if self.medium is None:
                self.medium = MediumProcess(self.scenario)
            if self.ids is None:
                ids = sc.station_ids
        try:
            if self.medium is not None:
                cpu = sim_cpu()
                self.medium_socket = self.medium.start(self.workdir, self.seed, ids)
                process = getattr(self.medium, "process", None)
                if isinstance(process, subprocess.Popen):
                    _pin(process.pid, cpu)
            for sid in ids:
                self.stations.append(self._spawn(exe, sid))
                _pin(self.stations[-1].process.pid, cpu)
            # All processes run before any is waited for: a medium that holds every station's
            # hello until all have connected cannot deadlock the start.
            for st in self.stations:
                st.port = self._read_port(st)
            deadline = time.monotonic() + self.start_timeout_s
            for st in self.stations:
                self._wait_ping(st, deadline)
        except BaseException:
            self.stop()
            raise
        return self.stations

    def _spawn(self, exe: Path | None, sid: int) -> Station:
        assert self.workdir is not None
        log = self.workdir / f"station-{sid}.log"
        flash = self.workdir / f"station-{sid}.flash"
        if self.board_of(sid) == "evk1000":
            # The EVK1000 image, byte for byte, in the emulator (uwbcal.evk1000): same flags,
            # same PTY line, same tunnel to the medium.
            cmd = [sys.executable, "-m", "uwbcal.evk1000", "--id", str(sid), "--flash", str(flash),
                   "--image", str(evk1000_image(self.image)), *self.extra_args]
        else:
            cmd = [str(exe or station_binary(self.binary)), "--id", str(sid), "--flash", str(flash),
                   *self.extra_args]
        if self.medium_socket:
            cmd += ["--medium", self.medium_socket]
        with open(log, "wb") as logf:
            proc = subprocess.Popen(
                cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=logf, start_new_session=True
            )
        return Station(sid, "", proc, log, flash)

    def _read_port(self, st: Station) -> str:
        """The pty path from the station's one line ``PTY <path>`` on stdout."""
        proc, sid, log = st.process, st.id, st.log_path
        assert proc.stdout is not None
        line = b""
        deadline = time.monotonic() + self.start_timeout_s
        with selectors.DefaultSelector() as sel:
            sel.register(proc.stdout, selectors.EVENT_READ)
            while not line.endswith(b"\n"):
                left = deadline - time.monotonic()
                if left <= 0 or not sel.select(left):
                    raise SimError(
                        f"station {sid} printed no PTY line within {self.start_timeout_s:g} s (log: {log})"
                    )
                chunk = os.read(proc.stdout.fileno(), 256)
                if not chunk:
                    code = proc.wait()
                    raise SimError(
                        f"station {sid} exited with code {code} before serving: {log_tail(log)} (log: {log})"
                    )
                line += chunk
        proc.stdout.close()
        text = line.decode(errors="replace").strip()
        if not text.startswith("PTY "):
            raise SimError(f"station {sid}: unexpected first line {text!r}")
        return text[4:]

    def _wait_ping(self, st: Station, deadline: float) -> None:
        dev: Device | None = None
        try:
            while True:
                if st.process.poll() is not None:
                    raise SimError(
                        f"station {st.id} died with code {st.process.returncode}: "
                        f"{log_tail(st.log_path)} (log: {st.log_path})"
                    )
                try:
                    if dev is None:
                        dev = Device.open(st.port, timeout=0.3, retries=0)
                    dev.ping()
                    return
                except UwbcalError as exc:
                    if time.monotonic() >= deadline:
                        raise SimError(
                            f"station {st.id} on {st.port} does not answer PING: {exc} (log: {st.log_path})"
                        ) from None
                    time.sleep(0.05)
        finally:
            if dev is not None:
                dev.close()

    def restart(self, sid: int) -> Station:
        """Cut station ``sid``'s power (SIGKILL) and start it again with the same flash file and
        medium, as a board that is unplugged and plugged back in; returns the new station (its
        pty is a new path) and waits until it answers PING."""
        i = next(k for k, st in enumerate(self.stations) if st.id == sid)
        old = self.stations[i]
        if old.process.poll() is None:
            old.process.kill()
        old.process.wait()
        st = self._spawn(station_binary(self.binary), sid)
        _pin(st.process.pid, sim_cpu() if self.medium is not None else None)
        self.stations[i] = st
        st.port = self._read_port(st)
        self._wait_ping(st, time.monotonic() + self.start_timeout_s)
        return st

    @property
    def ports(self) -> list[str]:
        """The stations' ports, in id order."""
        return [s.port for s in self.stations]

    def alive(self) -> list[Station]:
        """Stations whose process still runs."""
        return [s for s in self.stations if s.process.poll() is None]

    def stop(self, grace_s: float = 5.0) -> dict[int, int]:
        """SIGTERM every process started, SIGKILL after ``grace_s``; returns id -> exit code."""
        for st in self.stations:
            if st.process.poll() is None:
                st.process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + grace_s
        codes: dict[int, int] = {}
        for st in self.stations:
            try:
                st.returncode = st.process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                st.process.kill()
                st.returncode = st.process.wait()
            codes[st.id] = st.returncode
        if self.medium is not None:
            self.medium.stop()
        if self._own_workdir and self.workdir is not None and all(c == CLEAN_EXIT for c in codes.values()):
            shutil.rmtree(self.workdir, ignore_errors=True)
        return codes

    def __enter__(self) -> SimWorld:
        if not self.stations:
            self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
