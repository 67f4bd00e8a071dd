"""Kill the host mid-session (SIGKILL: no clean-up at all), then `--resume`: one complete
session, every record exactly once. Simulated stations, the real CLI as a subprocess."""

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
from uwbcal.simworld import SimWorld, repo_root

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
        proc.kill()                       # the host dies; the stations go on streaming into the void
    finally:
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
