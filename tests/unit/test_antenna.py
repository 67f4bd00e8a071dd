"""Per-station antenna delays (corrections/antenna.py): recovered on synthetic pairs, refused
when underdetermined, and the real four-node check of issue 14 (asil-lab runs 2026-02-24-01 and
2026-01-29-01, trimmed copies in tests/data with provenance)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from uwbcal import cli, dw1000
from uwbcal.commands import antenna as cmd
from uwbcal.corrections import antenna

DATA = Path(__file__).resolve().parents[1] / "data"
RUN_0224 = DATA / "asil4" / "run"
RUN_0129 = DATA / "asil4_0129" / "run"


def _pairs(delays: dict[int, float], dist: dict[tuple[int, int], float], noise: float,
           seed: int = 0) -> list[antenna.PairRanges]:
    rng = np.random.default_rng(seed)
    return [antenna.PairRanges(a, b, d, d + delays[a] + delays[b] + rng.normal(0, noise, 200))
            for (a, b), d in dist.items()]


def test_delays_recovered_with_honest_uncertainties() -> None:
    delays = {1: 77.10, 2: 77.05, 3: 77.18, 4: 77.02}
    dist = {(1, 2): 3.0, (1, 3): 5.0, (2, 3): 4.0, (1, 4): 2.0, (2, 4): 3.6, (3, 4): 4.5}
    sol = antenna.solve(_pairs(delays, dist, 0.03), "none")
    for s, c in delays.items():
        assert abs(sol.delay_m[s] - c) < 4 * sol.delay_sigma_m[s] + 2e-3
        assert sol.delay_sigma_m[s] < 0.01
    assert sol.antd_units(3) == round(77.18 / dw1000.METRES_PER_UNIT)
    assert max(abs(v) for v in antenna.prediction_errors(sol, _pairs(delays, dist, 0.03, 1)).values()) < 0.01


def test_three_stations_are_the_minimum_and_two_are_refused() -> None:
    d3 = {(1, 2): 3.0, (1, 3): 5.0, (2, 3): 4.0}
    sol = antenna.solve(_pairs({1: 0.1, 2: 0.2, 3: 0.3}, d3, 0.01), "none")
    assert sol.dof == 0 and abs(sol.delay_m[3] - 0.3) < 0.01
    with pytest.raises(ValueError, match="three or more"):
        antenna.solve(_pairs({1: 0.1, 2: 0.2}, {(1, 2): 3.0}, 0.01), "none")


def test_solution_round_trips() -> None:
    sol = antenna.solve(_pairs({1: 0.1, 2: 0.2, 3: 0.3}, {(1, 2): 3.0, (1, 3): 5.0, (2, 3): 4.0}, 0.01))
    assert antenna.AntennaSolution.from_dict(json.loads(json.dumps(sol.to_dict()))).delay_m == sol.delay_m


def test_real_four_nodes_calibrated_on_0224_cut_the_0129_error_by_half() -> None:
    """The issue's bar, in the direction it is met: delays + the generic power term fitted on
    2026-02-24-01 (0.39 .. 0.905 m) predict 2026-01-29-01 (0.907 .. 1.874 m). Recorded figures
    (docs/ANTENNA.md): MAE 12.4 cm uncalibrated (Decawave default delays) -> 5.0 cm (60 % cut)."""
    r = cmd.compare(cmd.asil_pairs(RUN_0224, None), cmd.asil_pairs(RUN_0129, None), "aps011")
    assert r["mae_m"]["calibrated"] <= 0.5 * r["mae_m"]["uncalibrated"], r["mae_m"]
    assert r["mae_m"]["calibrated"] < r["mae_m"]["one_z"]


def test_real_four_nodes_the_other_direction_is_not_met() -> None:
    """Calibrated on 2026-01-29-01, predicting 2026-02-24-01 does NOT beat Decawave's defaults
    (4.2 cm uncalibrated -> 6.2 cm): kept as a test so the docs' statement stays true."""
    r = cmd.compare(cmd.asil_pairs(RUN_0129, None), cmd.asil_pairs(RUN_0224, None), "aps011")
    assert r["mae_m"]["calibrated"] > r["mae_m"]["uncalibrated"]


def test_antenna_cli_json_and_out(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "antd.json"
    assert cli.main(["antenna", "asil", str(RUN_0224), "--check", str(RUN_0129), "--json",
                     "--out", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["solution"]["stations"] == [0, 1, 2, 3]
    assert set(doc["check"]["errors_m"]["calibrated"]) == {"0-1", "0-2", "0-3", "1-2", "1-3", "2-3"}
    assert antenna.AntennaSolution.from_dict(json.loads(out.read_text())).stations == [0, 1, 2, 3]


def test_simulated_fleet_with_power_curves_carries_to_another_geometry(tmp_path: Path) -> None:
    """Three simulated stations (scenarios/three_stations.toml, each with its own antenna-delay
    errors and power-bias curve): delays solved from ranges at the scenario's 3/4/5 m, corrected
    with the stations' own power curves (the paper's E1/E2), predict ranges at 1.2/1.6/2.0 m to
    a few mm; without the curves the geometry change leaves cm (the power bias moved)."""
    from uwbcal import vectorsim
    from uwbcal.physics.scenario import load_scenario

    sc = load_scenario("three_stations")
    def session(schedule: object, name: str, seed: int) -> Path:
        return vectorsim.simulate_session(sc, schedule, tmp_path / name, seed=seed)  # type: ignore[arg-type]

    power = [session(vectorsim.power_schedule(sc, 61, 200, step_db=0.5, tx=tx, rx=rx, distance_m=1.0),
                     f"p{rx}.db", rx) for tx, rx in ((1, 2), (2, 3), (3, 1))]
    cal, test = [], []
    for i, (a, b) in enumerate(((1, 2), (1, 3), (2, 3))):
        cal.append(session(vectorsim.twr_schedule(sc, [sc.distance_m(a, b)], per_distance=200, ref=a, tag=b),
                           f"a{a}{b}.db", i))
        test.append(session(vectorsim.twr_schedule(sc, [1.2 + 0.4 * i], per_distance=200, ref=a, tag=b),
                            f"b{a}{b}.db", 10 + i))
    with_curves = cmd.compare(cmd.session_pairs(cal, power), cmd.session_pairs(test, power), "none", 0.0)
    drift_only = cmd.compare(cmd.session_pairs(cal, []), cmd.session_pairs(test, []), "none", 0.0)
    assert with_curves["mae_m"]["calibrated"] < 0.005
    assert with_curves["mae_m"]["calibrated"] < 0.5 * with_curves["mae_m"]["one_z"]
    assert drift_only["mae_m"]["calibrated"] > 3 * with_curves["mae_m"]["calibrated"]
