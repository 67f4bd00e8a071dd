"""Vectorised sessions (uwbcal.vectorsim) and `uwbcal simulate`, against the truth they carry."""

from __future__ import annotations

import json

import numpy as np
import pytest
from uwbcal import cli, dw1000
from uwbcal import vectorsim as S
from uwbcal.physics import World, load_scenario
from uwbcal.physics import models as M
from uwbcal.sessions import columns
from uwbcal.sessions.store import Session

TU = dw1000.TIME_UNIT_S
C = dw1000.C_LIGHT


def drift_residual_m(rec: dict[str, np.ndarray]) -> np.ndarray:  # type: ignore[type-arg]
    """Eq. 1 of the paper on raw records, m (an independent re-statement for the tests)."""
    d12r = dw1000.wrap_diff(rec["rx2"], rec["rx1"])
    d12t = dw1000.wrap_diff(rec["tx2"], rec["tx1"])
    d13r = dw1000.wrap_diff(rec["rx3"], rec["rx1"])
    d13t = dw1000.wrap_diff(rec["tx3"], rec["tx1"])
    c12 = (d12r - d12t).astype(float)
    c13 = (d13r - d13t).astype(float)
    return np.asarray((c12 - c13 / d13t * d12t) * TU * C)


def test_columns_and_dtypes() -> None:
    w = World(load_scenario("paper_cable"))
    rec, truth = S.run_triplets(w, S.drift_schedule(w, 100))
    assert list(rec) == columns.names("triplets") and list(truth) == columns.names("truth_triplets")
    for name, typ, _, _ in columns.TRIPLET:
        assert rec[name].dtype == (np.int64 if typ == "INTEGER" else np.float64), name
        assert rec[name].shape == (100,)
    assert np.all(rec["tx1"] < 1 << 40) and np.all(rec["rx3"] < 1 << 40)


def test_drift_residual_vanishes_even_during_warmup() -> None:
    sc = load_scenario("paper_cable")
    w = World(sc, seed=3)
    rec, truth = S.run_triplets(w, S.drift_schedule(w, 20000, period_s=0.02, start_s=0.5))
    c12 = (dw1000.wrap_diff(rec["rx2"], rec["rx1"]) - dw1000.wrap_diff(rec["tx2"], rec["tx1"])) * TU * C
    assert abs(c12.mean()) > 1.0  # the uncorrected clock drift error is metres
    res = drift_residual_m(rec)
    assert abs(res.mean()) < 1e-4
    assert abs(truth["offset_ppm"][0] - truth["offset_ppm"][-1]) > 0.5  # the clocks were still warming


def test_short_spacing_offset_matches_the_interference_model() -> None:
    sc = load_scenario("paper_cable").with_effects(enabled={"timestamp_noise": False})
    w = World(sc, seed=1)
    r150, _ = S.run_triplets(w, S.drift_schedule(w, 4000, spacing_s=150e-6))
    r2ms, _ = S.run_triplets(w, S.drift_schedule(w, 4000, spacing_s=2e-3))
    shift = M.interference_shift_s(150e-6, 40.0, 120e-6)[()] * C  # P2 and P3 shifted, P1 not
    assert drift_residual_m(r150).mean() == pytest.approx(shift - shift / 2, abs=2e-4)
    assert abs(drift_residual_m(r2ms).mean()) < 1e-4


def test_power_sweep_residual_is_the_true_bias_difference() -> None:
    sc = load_scenario("paper_antenna")
    w = World(sc, seed=7)
    sched = S.power_schedule(w, steps=12, per_step=400, step_db=2.0)
    rec, truth = S.run_triplets(w, sched)
    res = drift_residual_m(rec)
    true = (truth["bias_s2"] - 0.5 * (truth["bias_s1"] + truth["bias_s3"])) * C
    for k in range(12):
        m = rec["step"] == k
        assert res[m].mean() == pytest.approx(true[m].mean(), abs=1e-3)
    assert np.all(np.diff([truth["rx_dbm2"][rec["step"] == k].mean() for k in range(12)]) < -1.0)
    assert np.ptp(truth["rx_dbm1"]) < 1e-9  # P1/P3 constant


def test_twr_all_effects_off_gives_the_distance() -> None:
    sc = load_scenario("paper_antenna").with_all_effects(False)
    w = World(sc)
    rec, truth = S.run_ranges(w, S.twr_schedule(w, [0.562, 2.0, 3.515], per_distance=50))
    rtt = dw1000.wrap_diff(rec["t2r"], rec["t1r"]) - dw1000.wrap_diff(rec["t2t"], rec["t1t"])
    d = 0.5 * rtt * TU * C
    assert np.all(np.abs(d - truth["distance_m"]) < 2 * dw1000.METRES_PER_UNIT)
    assert np.allclose(truth["tof_s"], truth["distance_m"] / C)
    assert list(rec) == columns.names("ranges") and set(rec["method"]) == {"paper"}


def test_twr_with_effects_is_biased_by_power() -> None:
    w = World(load_scenario("paper_antenna"), seed=2)
    rec, truth = S.run_ranges(w, S.twr_schedule(w, [0.562, 3.515], per_distance=300))
    ds = dw1000.wrap_diff(rec["t2r"], rec["t1r"]) * dw1000.wrap_diff(
        rec["t3t"], rec["t2t"]
    ) - dw1000.wrap_diff(rec["t2t"], rec["t1t"]) * dw1000.wrap_diff(rec["t3r"], rec["t2r"])
    den = (
        dw1000.wrap_diff(rec["t2r"], rec["t1r"])
        + dw1000.wrap_diff(rec["t3t"], rec["t2t"])
        + dw1000.wrap_diff(rec["t2t"], rec["t1t"])
        + dw1000.wrap_diff(rec["t3r"], rec["t2r"])
    )
    err = ds / den * TU * C - truth["distance_m"]
    near, far = err[:300].mean(), err[300:].mean()
    assert near < far - 0.05  # stronger signal -> earlier timestamps -> shorter ranges (APS011)


def test_schedule_from_records_reproduces_the_session() -> None:
    sc = load_scenario("two_stations")
    w = World(sc, seed=4)
    sched = S.power_schedule(w, steps=3, per_step=50, step_db=1.0)
    rec, _ = S.run_triplets(w, sched)
    back = S.schedule_from_records(rec)
    assert isinstance(back, S.TripletSchedule)
    for k, v in sched.as_dict().items():
        if k == "distance_m":
            assert np.allclose(back.distance_m, 2.0)
        else:
            assert np.array_equal(v, getattr(back, k)), k
    again, _ = S.run_triplets(World(sc, seed=4), back)
    assert np.array_equal(again["rx2"], rec["rx2"])
    rr, _ = S.run_ranges(World(sc), S.twr_schedule(sc, [1.0], per_distance=20, reply_s=2e-3, reply2_s=1e-3))
    rs = S.schedule_from_records(rr)
    assert isinstance(rs, S.RangeSchedule)
    # to within the TX antenna delay (257 ns) and the 8 ns grid
    assert np.allclose(rs.reply_s, 2e-3, atol=3e-7) and np.allclose(rs.reply2_s, 1e-3, atol=3e-7)


def test_run_is_reproducible_and_seed_dependent() -> None:
    sc = load_scenario("paper_cable")
    a, _ = S.run_triplets(World(sc, seed=1), S.drift_schedule(sc, 300))
    b, _ = S.run_triplets(World(sc, seed=1), S.drift_schedule(sc, 300))
    c, _ = S.run_triplets(World(sc, seed=2), S.drift_schedule(sc, 300))
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not np.array_equal(a["rx2"], c["rx2"])


def test_multiple_pairs_in_one_schedule() -> None:
    sc = load_scenario("two_stations")
    s12 = S.drift_schedule(sc, 100, tx=1, rx=2)
    s21 = S.drift_schedule(sc, 100, tx=2, rx=1, start_s=1.01)
    both = S.TripletSchedule(**{k: np.concatenate([v, getattr(s21, k)]) for k, v in s12.as_dict().items()})
    rec, _ = S.run_triplets(World(sc), both)
    assert set(rec["tx_station"][:100]) == {1} and set(rec["rx_station"][100:]) == {1}
    assert abs(drift_residual_m(rec).mean()) < 1e-3


def test_cli_simulate_writes_sessions(tmp_path: object, capsys: pytest.CaptureFixture[str]) -> None:
    from pathlib import Path

    out = Path(str(tmp_path)) / "d.db"
    assert (
        cli.main(
            ["simulate", "paper_cable", "--experiment", "drift", "--count", "50", "--out", str(out), "--json"]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out)
    assert summary["records"] == 50 and summary["table"] == "triplets"
    with Session.open(out) as s:
        assert s.count("triplets") == 50 and s.count("truth_triplets") == 50
        meta = s.meta
        assert (
            meta["kind"] == "simulated"
            and meta["experiment"] == "drift"
            and "[[stations]]" in meta["scenario"]
        )
        assert s.read("triplets")["spacing_s"][0] == pytest.approx(2e-3)
    assert cli.main(["simulate", "paper_cable", "-e", "drift", "--out", str(out)]) == 5  # refuses overwrite
    p = Path(str(tmp_path)) / "p.db"
    assert (
        cli.main(
            [
                "simulate",
                "paper_cable",
                "-e",
                "power",
                "--step-db",
                "3",
                "--steps",
                "5",
                "--per-step",
                "10",
                "--spacing",
                "150us",
                "--out",
                str(p),
            ]
        )
        == 0
    )
    with Session.open(p) as s:
        r = s.read("triplets")
        assert sorted(set(r["step"].tolist())) == [0, 1, 2, 3, 4]
        assert r["spacing_s"][0] == pytest.approx(150e-6)
    t = Path(str(tmp_path)) / "t.db"
    assert (
        cli.main(
            [
                "simulate",
                "paper_antenna",
                "-e",
                "twr",
                "--distances",
                "0.562,3.515",
                "--per-distance",
                "5",
                "--out",
                str(t),
                "--effects-off",
                "multipath,warmup",
            ]
        )
        == 0
    )
    with Session.open(t) as s:
        assert s.count("ranges") == 10 and s.meta["settings"]["effects_off"] == ["multipath", "warmup"]
    assert cli.main(["simulate", "no_such_scenario", "-e", "drift", "--out", str(t)]) == 7


def test_parse_duration() -> None:
    import argparse

    from uwbcal.commands.vectorsim import parse_duration

    assert parse_duration("2ms") == pytest.approx(2e-3)
    assert parse_duration("150us") == pytest.approx(150e-6)
    assert parse_duration("0.05") == pytest.approx(0.05)
    assert parse_duration("1.5e-3s") == pytest.approx(1.5e-3)
    for bad in ("fast", "2 parsecs", "-1ms", "0"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_duration(bad)


def test_cli_set_overrides(tmp_path: object) -> None:
    from pathlib import Path

    from uwbcal.physics import parse_scenario

    out = Path(str(tmp_path)) / "o.db"
    argv = ["simulate", "two_stations", "-e", "drift", "--count", "10", "--out", str(out)]
    assert cli.main([*argv, "--set", "interference.amplitude_ps=12.5", "--set", "warmup.x=1"]) == 7
    assert cli.main([*argv, "--set", "interference.amplitude_ps=12.5"]) == 0
    with Session.open(out) as s:
        sc = parse_scenario(s.meta["scenario"])
        assert sc.effects["interference"].values()["amplitude_ps"] == 12.5
