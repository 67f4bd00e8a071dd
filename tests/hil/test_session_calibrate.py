"""End-to-end sessions against simulated stations: the firmware in the loop, the medium, the
physics World, the real protocol and the `uwbcal calibrate` / `drift` / `range` commands.

- a short calibration completes with no lost record and recovers the scenario's true
  power-bias curve within 1 cm RMS;
- the firmware-in-the-loop session and the vectorised simulator (uwbcal.vectorsim, same
  scenario, same schedule) agree within their noise, step by step.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from uwbcal import cli, dw1000
from uwbcal.corrections import analysis, drift
from uwbcal.physics.scenario import load_scenario
from uwbcal.physics.world import World
from uwbcal.sessions.store import Session
from uwbcal.simstations import SimWorld, repo_root

SCENARIO = repo_root() / "scenarios" / "two_stations.toml"
# 10 steps of 3 dB from the top gain: P2 from about -65 dBm to -92 dBm at 2 m, so that several
# steps lie below -85 dBm where the chip's RX level estimate is right.
STEPS, STEP_DB, PER_STEP = 10, 3.0, 100


def _calibrate(ports: list[str], out: Path, capsys: pytest.CaptureFixture[str],
               *extra: str) -> dict[str, Any]:
    rc = cli.main(["calibrate", "--tx", ports[0], "--rx", ports[1], "--steps", str(STEPS), "--step-db",
                   str(STEP_DB), "--per-step", str(PER_STEP), "--spacing", "2ms", "--out", str(out),
                   "--no-progress", "--json", *extra])
    text = capsys.readouterr().out
    assert rc == 0, text
    return dict(json.loads(text.strip().splitlines()[-1]))


def test_short_calibrate_recovers_the_true_curve(sim_stations: Callable[..., SimWorld], tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    world = sim_stations(scenario=SCENARIO)
    out = _calibrate(world.ports, tmp_path / "cal.db", capsys)
    run = out["run"]
    assert run["complete"] and run["records"] == STEPS * PER_STEP
    assert run["losses"]["lost_frames"] == 0 and run["losses"]["n_missing"] == 0
    assert run["counters"]["rx"]["dropped"] == 0 and run["counters"]["tx"]["late"] == 0
    with Session.open(tmp_path / "cal.db", readonly=True) as s:
        tr = s.read("triplets")
    assert sorted(tr["seq"].tolist()) == list(range(STEPS * PER_STEP))        # no duplicate, no gap
    assert np.bincount(tr["step"]).tolist() == [PER_STEP] * STEPS
    # Truth: the scenario's power bias at the true RX powers of P2 and P1/P3 (World, same scenario).
    cal = out["analysis"]["calibrations"][0]
    tx, rx = cal["tx_station"], cal["rx_station"]
    truth_world = World(load_scenario(SCENARIO))
    gains2 = np.array([st["gain2"] for st in cal["steps"]])
    p2 = truth_world.propagation(tx, rx, gains2)[0]
    p13 = truth_world.propagation(tx, rx, np.array([int(tr["gain13"][0])]))[0]
    truth_m = (truth_world.power_bias_s(rx, p2) - truth_world.power_bias_s(rx, p13)) * dw1000.C_LIGHT
    got_m = np.array([st["error_s"] for st in cal["steps"]]) * dw1000.C_LIGHT
    rms = float(np.sqrt(np.mean((got_m - truth_m) ** 2)))
    assert np.ptp(truth_m) > 0.05          # the curve spans several cm: the comparison means something
    assert rms < 0.01, f"recovered curve is {rms * 100:.2f} cm RMS from the truth"


def test_firmware_in_the_loop_agrees_with_the_vectorised_simulator(
        sim_stations: Callable[..., SimWorld], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    world = sim_stations(scenario=SCENARIO)
    _calibrate(world.ports, tmp_path / "fil.db", capsys, "--no-analysis")
    with Session.open(tmp_path / "fil.db", readonly=True) as s:
        fil = dict(s.read("triplets"))
    # The same schedule (times, gains, stations) played by the vectorised simulator with
    # another run seed: independent noise, same world.
    from uwbcal import vectorsim

    sched = vectorsim.schedule_from_records(fil)
    assert isinstance(sched, vectorsim.TripletSchedule)
    vec, _truth = vectorsim.run_triplets(World(load_scenario(SCENARIO), seed=12345), sched)
    a = analysis.calibrate_power_records(fil)
    b = analysis.calibrate_power_records(vec)
    assert a.keys() == b.keys() and len(a) == 1
    sa, sb = next(iter(a.values())).to_dict()["steps"], next(iter(b.values())).to_dict()["steps"]
    assert len(sa) == len(sb) == STEPS
    for x, y in zip(sa, sb, strict=True):
        assert x["gain2"] == y["gain2"]
        sem = np.hypot(x["error_sem_s"], y["error_sem_s"])
        assert abs(x["error_s"] - y["error_s"]) < 5 * sem + 2e-12, (x, y)
        assert abs(x["measured_dbm"] - y["measured_dbm"]) < 5 * np.hypot(x["measured_sem_db"],
                                                                          y["measured_sem_db"]) + 0.05
    # Spread per step, robust to the scenario's multipath outliers (2 % of receptions, so about
    # 6 % of triplets): standard deviation of the central 84 %.
    for k in range(STEPS):
        ra, rb = _robust_std(fil, k), _robust_std(vec, k)
        assert 0.7 < ra / rb < 1.4, (k, ra, rb)


def _robust_std(rec: dict[str, Any], step: int) -> float:
    m = np.asarray(rec["step"]) == step
    d = drift.triplet_diffs(*(np.asarray(rec[c])[m] for c in ("tx1", "tx2", "tx3", "rx1", "rx2", "rx3")))
    c = np.sort(drift.c12_corrected(d))
    cut = int(0.08 * c.size)
    return float(np.std(c[cut:c.size - cut]))
