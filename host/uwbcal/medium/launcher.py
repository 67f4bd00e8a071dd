"""Start the medium as its own process (uwbcal.simstations.MediumLauncher).

    launcher = MediumProcess(scenario=Path("scenarios/two_stations.toml"))
    sock = launcher.start(workdir, seed, [1, 2])      # then stations get --medium sock
    ...
    launcher.move(2, (5.0, 0.0, 1.0))                 # control socket: move a station
    launcher.stop()

The control socket (``<socket>.ctl``) takes one text command per line and answers one line:
``move ID X Y Z`` (m), ``where ID``, ``stats``.
"""

from __future__ import annotations

import os
import selectors
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from uwbcal.errors import UwbcalError


class MediumError(UwbcalError):
    """The medium could not be started, died, or refused a control command."""

    exit_code = 8


class MediumProcess:
    """One ``python -m uwbcal.medium`` process."""

    def __init__(self, scenario: str | os.PathLike[str], *, log_dir: bool = False, pace_idle: bool = True,
                 start_timeout_s: float = 20.0) -> None:
        self.scenario = Path(scenario)
        self.log_dir = log_dir
        self.pace_idle = pace_idle
        self.start_timeout_s = start_timeout_s
        self.process: subprocess.Popen[bytes] | None = None
        self.socket_path: str | None = None
        self.log_path: Path | None = None

    def start(self, workdir: Path, seed: int | None, station_ids: Sequence[int]) -> str:
        """Start the medium; return the unix socket path stations connect to.

        ``seed`` None keeps the scenario's seed. ``station_ids`` is informational: the medium
        waits for the scenario's stations.
        """
        workdir.mkdir(parents=True, exist_ok=True)
        # unix socket paths are limited to ~100 bytes: use a short name in the workdir
        sock = str(workdir / "medium.sock")
        if len(sock) > 100:
            raise MediumError(f"socket path too long for a unix socket: {sock}")
        self.log_path = workdir / "medium.log"
        cmd = [sys.executable, "-m", "uwbcal.medium", "--scenario", str(self.scenario), "--socket", sock,
               "--verbose"]
        if seed is not None:
            cmd += ["--seed", str(seed)]
        if self.log_dir:
            cmd += ["--log-dir", str(workdir)]
        if not self.pace_idle:
            cmd.append("--no-pace")
        with open(self.log_path, "wb") as logf:
            self.process = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                            stderr=logf, start_new_session=True)
        assert self.process.stdout is not None
        line = b""
        deadline = time.monotonic() + self.start_timeout_s
        with selectors.DefaultSelector() as sel:
            sel.register(self.process.stdout, selectors.EVENT_READ)
            while not line.endswith(b"\n"):
                left = deadline - time.monotonic()
                if left <= 0 or not sel.select(left):
                    self.stop()
                    raise MediumError(f"the medium did not start within {self.start_timeout_s:g} s "
                                      f"(log: {self.log_path})")
                chunk = os.read(self.process.stdout.fileno(), 256)
                if not chunk:
                    code = self.process.wait()
                    raise MediumError(f"the medium exited with code {code}: {log_tail(self.log_path)}")
                line += chunk
        self.process.stdout.close()
        if not line.startswith(b"medium: listening on "):
            self.stop()
            raise MediumError(f"unexpected first line from the medium: {line!r}")
        self.socket_path = sock
        return sock

    def control(self, command: str, timeout_s: float = 10.0) -> str:
        """Send one control command; return the answer line (MediumError on 'error ...')."""
        if self.socket_path is None:
            raise MediumError("the medium is not running")
        return control(self.socket_path, command, timeout_s)

    def move(self, station: int, position_m: tuple[float, float, float]) -> None:
        """Move a station to a new position, m."""
        x, y, z = position_m
        self.control(f"move {station} {x!r} {y!r} {z!r}")

    def stop(self) -> None:
        """SIGTERM the medium (SIGKILL after 5 s); idempotent."""
        p = self.process
        if p is None or p.poll() is not None:
            return
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(5.0)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def control(socket_path: str, command: str, timeout_s: float = 10.0) -> str:
    """One command on a medium's control socket (``<socket>.ctl``); returns the answer line."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(timeout_s)
        try:
            s.connect(socket_path + ".ctl")
            s.sendall(command.encode() + b"\n")
            data = b""
            while not data.endswith(b"\n"):
                chunk = s.recv(4096)
                if not chunk:
                    break
                data += chunk
        except OSError as exc:
            raise MediumError(f"medium control {command!r}: {exc}") from None
    answer = data.decode(errors="replace").strip()
    if not answer.startswith("ok"):
        raise MediumError(f"medium control {command!r}: {answer or 'no answer'}")
    return answer


def log_tail(path: Path, lines: int = 3) -> str:
    """The last ``lines`` lines of a child process's log on one line, for an error message."""
    try:
        text = path.read_text(errors="replace").strip().splitlines()
    except OSError:
        return "(no log)"
    return " | ".join(text[-lines:]) if text else "(empty log)"
