"""SIGKILL at the worst moments, then `--resume`: one complete session, every record exactly once.

- the host killed mid-session (no clean-up at all), and again while it resumes;
- the receiving station killed mid-session (a power cut): the host stops with one line that
  names `--resume` and no traceback, the station comes back on a new pty, `--resume --rx NEW`
  completes the session.
Simulated stations, the real CLI as a subprocess. What this cannot see: a board's USB
re-enumeration delay, and the medium's clock (a simulated station restarts in virtual time)."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from uwbcal import cli
from uwbcal.sessions.store import Session
from uwbcal.simstations import SimWorld, repo_root

SCENARIO = repo_root() / "scenarios" / "two_stations.toml"


def _count(db: Path) -> int:
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1.0) as c:
            return int(c.execute("SELECT count(*) FROM triplets").fetchone()[0])
    except sqlite3.Error:
        return 0


@pytest.mark.parametrize("command,extra,total", [
    ("calibrate", ["--steps", "6", "--step-db", "3", "--per-step", "150"], 900),
    ("drift", ["--count", "900"], 900),
])
def test_killed_host_resumes_without_duplicates_or_gaps(
        sim_stations: Callable[..., SimWorld], tmp_path: Path, capsys: pytest.CaptureFixture[str],
        command: str, extra: list[str], total: int) -> None:
    world = sim_stations(scenario=SCENARIO)
    tx, rx = world.ports
    db = tmp_path / "s.db"
    env = dict(os.environ, PYTHONPATH=str(repo_root() / "host"))
    proc = subprocess.Popen([sys.executable, "-m", "uwbcal", command, "--tx", tx, "--rx", rx, *extra,
                             "--spacing", "2ms", "--out", str(db), "--no-progress", "--no-analysis"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while _count(db) < total // 4:
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            assert time.monotonic() < deadline, "no records arrived"
            time.sleep(0.02)
    finally:
        proc.kill()                       # the host dies; the stations go on streaming into the void
        proc.wait()
    before = _count(db)
    assert 0 < before < total, before      # really killed mid-session
    rc = cli.main([command, "--resume", str(db), "--no-progress", "--no-analysis", "--json"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert rc == 0 and out["run"]["complete"], out
    with Session.open(db, readonly=True) as s:
        tr = s.read("triplets")
        runs = s.results()["runs"]
    seq = tr["seq"]
    assert seq.size == total and np.unique(seq).size == total           # no duplicate
    assert seq.min() == 0 and seq.max() == total - 1                    # no gap
    assert (np.diff(tr["t_s"][np.argsort(seq)]) > 0).all()              # time runs on across the resume
    if command == "calibrate":
        per = total // 6
        assert np.bincount(tr["step"]).tolist() == [per] * 6               # steps continued, not restarted
        gains = {int(k): int(g) for k, g in zip(tr["step"], tr["gain2"], strict=True)}
        assert len(set(gains.values())) == 6
    assert runs[-1]["name"] == command and runs[-1]["complete"]


EXTRA = ["--steps", "6", "--step-db", "3", "--per-step", "150", "--spacing", "2ms"]
TOTAL = 900


def _host(args: list[str]) -> subprocess.Popen[bytes]:
    env = dict(os.environ, PYTHONPATH=str(repo_root() / "host"))
    return subprocess.Popen([sys.executable, "-m", "uwbcal", "calibrate", *args, "--no-progress",
                             "--no-analysis"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _wait_count(proc: subprocess.Popen[bytes], db: Path, at_least: int) -> None:
    deadline = time.monotonic() + 120
    while _count(db) < at_least:
        assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
        assert time.monotonic() < deadline, "no records arrived"
        time.sleep(0.01)


def _check_complete(db: Path) -> None:
    with Session.open(db, readonly=True) as s:
        tr = s.read("triplets")
        runs = s.results()["runs"]
    assert sorted(tr["seq"].tolist()) == list(range(TOTAL))                # no duplicate, no gap
    assert np.bincount(tr["step"]).tolist() == [TOTAL // 6] * 6
    assert runs[-1]["complete"]


def _resume_completes(db: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> None:
    rc = cli.main(["calibrate", "--resume", str(db), *extra, "--no-progress", "--no-analysis", "--json"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert rc == 0 and out["run"]["complete"], out
    _check_complete(db)


def test_host_killed_mid_resume_then_resumed(sim_stations: Callable[..., SimWorld], tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    world = sim_stations(scenario=SCENARIO)
    tx, rx = world.ports
    db = tmp_path / "s.db"
    proc = _host(["--tx", tx, "--rx", rx, *EXTRA, "--out", str(db)])
    try:
        _wait_count(proc, db, TOTAL // 4)
    finally:
        proc.kill()
        proc.wait()
    first = _count(db)
    proc = _host(["--resume", str(db)])
    try:
        _wait_count(proc, db, first + TOTAL // 4)
    finally:
        proc.kill()                           # killed again, while resuming (or the wait failed)
        proc.wait()
    assert first < _count(db) < TOTAL
    _resume_completes(db, capsys)


def test_station_killed_restarted_then_resumed(sim_stations: Callable[..., SimWorld], tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    world = sim_stations(scenario=SCENARIO)
    tx, rx = world.ports
    db = tmp_path / "s.db"
    proc = _host(["--tx", tx, "--rx", rx, *EXTRA, "--out", str(db), "--timeout", "0.5", "--retries", "2"])
    try:
        _wait_count(proc, db, TOTAL // 4)
        new = world.restart(world.stations[1].id)      # power cut of the receiver, then back
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = err.decode()
    assert proc.returncode not in (0, 1), text          # a link error's own exit code
    assert "Traceback" not in text and len(text.strip().splitlines()) == 1, text
    assert "--resume" in text and "went away" in text and "multiple access" not in text, text
    before = _count(db)
    assert 0 < before < TOTAL
    _resume_completes(db, capsys, "--rx", new.port)


def test_resume_fills_holes_in_the_middle(sim_stations: Callable[..., SimWorld], tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    world = sim_stations(scenario=SCENARIO)
    tx, rx = world.ports
    db = tmp_path / "s.db"
    assert cli.main(["calibrate", "--tx", tx, "--rx", rx, *EXTRA, "--out", str(db), "--no-progress",
                     "--no-analysis", "--json"]) == 0
    capsys.readouterr()
    holes = [*range(100, 150), 300, 451, 899]            # in the middle, across steps, and the last
    with sqlite3.connect(db) as c:
        gain_of_step = dict(c.execute("SELECT DISTINCT step, gain2 FROM triplets").fetchall())
        c.executemany("DELETE FROM triplets WHERE seq = ?", [(s,) for s in holes])
    assert _count(db) == TOTAL - len(holes)
    _resume_completes(db, capsys)
    with Session.open(db, readonly=True) as s:
        tr = s.read("triplets")
    refilled = np.isin(tr["seq"], holes)
    assert refilled.sum() == len(holes)
    for seq, step, gain in zip(tr["seq"][refilled], tr["step"][refilled], tr["gain2"][refilled], strict=True):
        assert step == seq // (TOTAL // 6) and gain == gain_of_step[step]     # measured at its own step
