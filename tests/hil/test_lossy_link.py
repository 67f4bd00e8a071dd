"""Nothing lost on a bad link: a calibration through a lossy man-in-the-middle (uwbcal.link.lossy)
on both station links, each byte dropped, duplicated or corrupted with probability 1e-3 in each
direction, ends complete, with 0 missing and 0 duplicate records, and its power curve equals a
clean run's within noise. What this cannot see: faults that are not independent per byte (a
cable pulled for seconds is the SIGKILL/resume tests' job), and a real USART's timing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from uwbcal import cli
from uwbcal.sessions.store import Session
from uwbcal.simstations import SimWorld, repo_root

SCENARIO = repo_root() / "scenarios" / "two_stations.toml"
STEPS, STEP_DB, PER_STEP = 10, 3.0, 100
P = "1e-3"


@contextmanager
def lossy(ports: list[str], seed: int) -> Iterator[list[str]]:
    """The ports of a lossy proxy in front of ``ports`` (drop, dup and corrupt at P each)."""
    proc = subprocess.Popen([sys.executable, "-m", "uwbcal.link.lossy", "--drop", P, "--dup", P,
                             "--corrupt", P, "--seed", str(seed), *ports],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        out = [proc.stdout.readline().split()[-1] for _ in ports]
        yield out
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
        print(err)


def _calibrate(tx: str, rx: str, out: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    rc = cli.main(["calibrate", "--tx", tx, "--rx", rx, "--steps", str(STEPS), "--step-db", str(STEP_DB),
                   "--per-step", str(PER_STEP), "--spacing", "2ms", "--out", str(out), "--no-progress",
                   "--json", "--timeout", "0.5"])
    text = capsys.readouterr().out
    assert rc == 0, text
    return dict(json.loads(text.strip().splitlines()[-1]))


def test_lossy_links_lose_nothing(sim_stations: Callable[..., SimWorld], tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    world = sim_stations(scenario=SCENARIO)
    clean = _calibrate(world.ports[0], world.ports[1], tmp_path / "clean.db", capsys)
    with lossy(world.ports, seed=int(os.environ.get("UWBCAL_LOSSY_SEED", "7"))) as (tx, rx):
        bad = _calibrate(tx, rx, tmp_path / "lossy.db", capsys)
    assert "analysis" in clean and "analysis" in bad, (clean.get("analysis_error"), bad.get("analysis_error"))
    run = bad["run"]
    print(json.dumps(run["losses"] | {"missing_seqs": None}))
    total = STEPS * PER_STEP
    assert run["complete"] and run["records"] == total and run["losses"]["n_missing"] == 0
    # the link really was bad: frames were lost and got back or re-measured
    assert run["losses"]["lost_frames"] + run["losses"]["index_gaps"] > 0
    assert run["losses"]["fetched"] + run["losses"]["remeasured"] > 0
    with Session.open(tmp_path / "lossy.db", readonly=True) as s:
        tr = s.read("triplets")
    assert sorted(tr["seq"].tolist()) == list(range(total))                 # 0 missing, 0 duplicate
    assert np.bincount(tr["step"]).tolist() == [PER_STEP] * STEPS
    gain_of_step = dict(zip(tr["step"].tolist(), tr["gain2"].tolist(), strict=True))
    assert len(set(gain_of_step.values())) == STEPS                         # one gain per step
    # the power curve equals the clean run's within noise, step by step
    sa = clean["analysis"]["calibrations"][0]["steps"]
    sb = bad["analysis"]["calibrations"][0]["steps"]
    assert len(sa) == len(sb) == STEPS
    for x, y in zip(sa, sb, strict=True):
        assert x["gain2"] == y["gain2"]
        sem = np.hypot(x["error_sem_s"], y["error_sem_s"])
        assert abs(x["error_s"] - y["error_s"]) < 5 * sem + 2e-12, (x, y)
