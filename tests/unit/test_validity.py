"""Calibration validity (corrections/validity.py) and the TWR analysis' warnings: ranging
outside the swept RX levels, and a declared distance the ranges contradict."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from uwbcal import vectorsim
from uwbcal.commands import analyze as an
from uwbcal.corrections import analysis, validity
from uwbcal.physics.scenario import load_scenario
from uwbcal.sessions.store import Session


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("validity")
    sc = load_scenario("paper_antenna")
    out = {}
    for name, tx, rx, seed in (("p12", 2, 1, 4), ("p21", 1, 2, 5)):
        sch = vectorsim.power_schedule(sc, 61, 200, step_db=0.5, tx=tx, rx=rx, distance_m=2.0)
        out[name] = vectorsim.simulate_session(sc, sch, d / f"{name}.db", seed=seed)
    for dist, seed in ((1.0, 6), (2.0, 7)):
        out[f"twr{dist:g}"] = vectorsim.simulate_session(
            sc, vectorsim.twr_schedule(sc, [dist], per_distance=300), d / f"twr{dist:g}.db", seed=seed)
    return out


def _twr(sessions: dict[str, Path], name: str) -> dict:  # type: ignore[type-arg]
    with Session.open(sessions[name], readonly=True) as s:
        return an.analyze_twr_session(s, None, [sessions["p12"], sessions["p21"]], None)


def test_ranging_closer_than_the_calibration_warns_with_a_closer_distance(sessions: dict[str, Path]) -> None:
    r = _twr(sessions, "twr1")
    cov = r["corrections"]["coverage"]
    assert {c["station"] for c in cov} == {1, 2}
    assert all(c["n_above"] > 0.9 * c["n"] for c in cov)     # 1 m is ~6 dB above a sweep made at 2 m
    assert len(r["warnings"]) >= 2 and all("extrapolated" in w for w in r["warnings"][:2])
    assert all(c["closer_m"] == pytest.approx(1.0) for c in cov)
    assert "uwbcal calibrate" in r["warnings"][0] and "calibrated at 2 m" in r["warnings"][0]
    assert r["corrections"]["power_curves"]["applied"] == 300
    assert r["corrections"]["drift_eq1"]["applied"] == 300


def test_ranging_at_the_calibration_distance_does_not_warn(sessions: dict[str, Path]) -> None:
    r = _twr(sessions, "twr2")
    cov = r["corrections"]["coverage"]
    assert all(c["n_above"] + c["n_below"] <= validity.WARN_FRACTION * c["n"] for c in cov)
    assert r["warnings"] == []


def test_a_wrong_declared_distance_is_questioned(sessions: dict[str, Path]) -> None:
    with Session.open(sessions["twr2"], readonly=True) as s:
        rg = dict(s.read("ranges"))
    n = len(rg["seq"])
    right = analysis.analyze_twr_records(rg, distances=np.full(n, 2.0))
    assert not any("declared distance" in w for w in right["warnings"])
    wrong = analysis.analyze_twr_records(rg, distances=np.full(n, 1.5))    # the README's old example
    assert any("declared distance 1.5 m" in w for w in wrong["warnings"])


def test_one_wrong_distance_among_several_is_named() -> None:
    d = np.repeat([1.0, 2.0, 4.0, 7.0], 50)
    raw = d + 0.08 + np.random.default_rng(1).normal(0, 0.01, d.size)
    assert analysis.distance_warnings(d, np.unique(d), raw) == []
    declared = np.where(d == 4.0, 4.5, d)
    w = analysis.distance_warnings(declared, np.unique(declared), raw)
    assert len(w) == 1 and "4.5 m" in w[0]


def test_validity_round_trips() -> None:
    v = validity.Validity(station=2, swept_measured_dbm=(-100.0, -80.0), swept_real_dbm=(-101.0, -78.0),
                          trusted_below_dbm=-85.0, calibrated_at_m=2.0)
    assert validity.Validity.from_dict(v.to_dict()) == v
