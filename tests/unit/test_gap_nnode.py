"""`uwbcal gap` on N-node sessions: the believed N-station world (gap/nnode.py), the per-station TX
jitter candidate, and checks on simulated four-node asil-like sessions read back through the
importer (gap/blind_nnode.py), with departures from the independent forms of gap/departures.py.

The simulated "reality" is two_stations plus two stations of the catalogue's hardware with their
own clock offsets, at the pair distances of the real run 2026-02-24-01 (tests/data/asil4), 40 s
(148 triplets per direction). The diagnosis believes two_stations alone and builds the rest.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from uwbcal.gap import blind_nnode, engine, model, nnode
from uwbcal.gap import departures as dep
from uwbcal.gap import observables as obs_mod
from uwbcal.importers import asil
from uwbcal.physics.scenario import Scenario, Station, load_scenario

DATA = Path(__file__).resolve().parents[1] / "data"
ASIL4 = DATA / "asil4" / "run"
ASIL2 = DATA / "asil" / "run"
#: Pair distances of 2026-02-24-01 (m), in scenario ids (asil node k is station k + 1).
DIST = {(1, 2): 0.75, (1, 3): 0.55, (1, 4): 0.905, (2, 3): 0.62, (2, 4): 0.39, (3, 4): 0.51}
CFG = engine.Config(n_seeds=12, n_seeds_signature=2, n_boot=500)


def _truth() -> Scenario:
    """two_stations plus stations 3 and 4 at the catalogue's hardware, with clock offsets of their own."""
    sc = load_scenario("two_stations")
    return sc.with_new_station(3, ppm=1.5, position_m=(0.0, 0.55, 1.0)).with_new_station(
        4, ppm=2.4, position_m=(-0.9, 0.0, 1.0)
    )


def _diagnose(real: dict[str, Any], seed: int) -> tuple[engine.Diagnosis, nnode.BelievedWorld]:
    """The diagnosis `uwbcal gap` runs (one ensemble, reduced seeds) against two_stations."""
    world = nnode.believed_world(real, load_scenario("two_stations"))
    sc = world.scenario
    cfg = engine.Config(**{**CFG.__dict__, "seed": seed})
    d = engine.diagnose(
        real,
        model.physics_simulator(real, sc),
        model.candidates(sc),
        cfg,
        subsampled=model.subsampled_simulators(real, sc),
        shapes=model.clock_shapes(real, sc),
        refine=model.shape_refiner(sc),
    )
    return d, world


def _rate_by_direction(rec: Mapping[str, Any]) -> dict[tuple[int, int], float]:
    r = obs_mod.observables(rec)["clock_rate_ppm"]
    tx, rx = np.asarray(rec["tx_station"]), np.asarray(rec["rx_station"])
    return {
        (int(a), int(b)): float(np.median(r[(tx == a) & (rx == b)]))
        for a, b in {(int(a), int(b)) for a, b in zip(tx, rx, strict=True)}
    }


# --- the believed world --------------------------------------------------------------------------


def test_believed_world_of_the_real_four_node_excerpt() -> None:
    imp = asil.load_run(ASIL4)
    real = model.since_power_on(imp.triplets, imp.meta)
    sc = load_scenario("two_stations")
    world = nnode.believed_world(real, sc)
    assert world.mapping == {0: 1, 1: 2, 2: 3, 3: 4}
    assert world.scenario.stations[:2] == sc.stations  # the described stations, unchanged
    assert [a["scenario_station"] for a in world.added] == [3, 4]
    for sid in (3, 4):  # the catalogue's hardware, apart from the fitted clock and the placement
        st = world.scenario.station(sid)
        expect = Station(
            id=sid, name=f"station{sid}", uid=f"SIM-{sid:04d}", position_m=st.position_m, ppm=st.ppm
        )
        assert st == expect
    # placed at the session's distance from the reference (real node 0)
    ref = np.asarray(sc.station(1).position_m)
    assert np.linalg.norm(np.asarray(world.scenario.station(3).position_m) - ref) == pytest.approx(0.55)
    assert np.linalg.norm(np.asarray(world.scenario.station(4).position_m) - ref) == pytest.approx(0.905)
    # the fitted clocks reproduce the rates of the directions they were fitted to (the reference's
    # and among added stations), and leave the believed offset of station 2 (real 1) a gap
    sim = model.physics_simulator(real, world.scenario.with_effects(enabled={"clock_wander": False}))
    rr, rs = _rate_by_direction(real), _rate_by_direction(sim((), 3))
    for pair in [(0, 2), (2, 0), (0, 3), (3, 0), (2, 3), (3, 2)]:
        assert abs(rr[pair] - rs[pair]) < 0.01, pair
    assert abs(rr[(0, 1)] - rs[(0, 1)]) > 0.5
    js = world.to_json()
    assert js["real_to_scenario"] == {"0": 1, "1": 2, "2": 3, "3": 4} and js["reference_station"] == 1
    text = "\n".join(world.describe())
    assert "the believed world has 2 more" in text and "added station 3 (real 2)" in text


def test_two_node_sessions_keep_their_scenario() -> None:
    real = asil.load_run(ASIL2).triplets
    sc = load_scenario("two_stations")
    world = nnode.believed_world(real, sc)
    assert world.scenario is sc and not world.added and world.describe() == []
    assert world.mapping == {0: 1, 1: 2}


def test_equal_ids_when_the_session_begins_with_the_scenarios() -> None:
    tx = np.array([1, 2, 3, 4, 1, 3])
    rec = {"tx_station": tx, "rx_station": np.array([2, 3, 4, 1, 3, 1])}
    assert nnode._new_ids([1, 2, 3, 4], [1, 2]) == [3, 4]
    assert nnode._new_ids([0, 1, 2, 3], [1, 2]) == [3, 4]
    assert nnode._real_ids(rec) == [1, 2, 3, 4]


def test_tx_scale_candidates_need_three_transmitters() -> None:
    sc4 = _truth()
    cands = model.candidates(sc4)
    tx = [c for c in cands if c.knob.endswith(":tx_noise_scale")]
    assert [c.effect for c in tx] == [f"timestamp_noise_tx[{i}]" for i in (1, 2, 3, 4)]
    assert all(c.baseline == 1.0 and c.depends_on == "timestamp_noise" for c in tx)
    assert all(c.needs == ("tx_station", 3) for c in tx)
    two = {"tx_station": np.array([1, 2, 1]), "rx_station": np.array([2, 1, 2])}
    keep, skip = engine.offered(cands, two)
    assert set(tx) <= set(skip) and not any(c.knob.endswith(":noise_scale") for c in skip)
    three = {"tx_station": np.array([1, 2, 3]), "rx_station": np.array([2, 3, 1])}
    keep, skip = engine.offered(cands, three)
    assert set(tx) <= set(keep)
    # a two-station scenario has no TX candidates at all: two-node diagnoses are unchanged
    two_cands = model.candidates(load_scenario("two_stations"))
    assert not any(c.knob.endswith(":tx_noise_scale") for c in two_cands)


def test_spacing_classes_pool_the_turns_of_four_nodes_only() -> None:
    four = asil.load_run(ASIL4).triplets
    keys = obs_mod.regimes(four).keys["spacing"]
    assert set(keys.tolist()) == {obs_mod.SPACING_POOLED}
    assert obs_mod.label("spacing", obs_mod.SPACING_POOLED) == "all spacings"
    two = asil.load_run(ASIL2).triplets
    k2 = obs_mod.regimes(two).keys["spacing"]
    assert np.array_equal(k2, obs_mod._bins(np.asarray(two["spacing_s"]) * 1e3, 0.1))
    # the same spacings from only two transmitters keep their 0.1 ms classes
    sel = np.isin(np.asarray(four["tx_station"]), [0, 1])
    k = obs_mod.spacing_keys(np.asarray(four["spacing_s"])[sel] * 1e3, np.asarray(four["tx_station"])[sel])
    assert obs_mod.SPACING_POOLED not in k.tolist()


def test_time_blocks_shrink_only_for_short_n_node_sessions() -> None:
    """Ten blocks unless a direction's block would hold fewer than min_feature records."""
    four = asil.load_run(ASIL4).triplets  # 6..16 records per direction
    assert nnode.time_blocks(four, 8, 10) == nnode.MIN_TIME_BLOCKS
    assert nnode.time_blocks(asil.load_run(ASIL2).triplets, 8, 10) == 10  # two nodes: never changed
    sim = blind_nnode.make_session(_truth(), DIST, 40.0, 0)  # 148 records per direction
    assert nnode.time_blocks(sim, 8, 10) == 10
    short = blind_nnode.make_session(_truth(), DIST, 15.0, 0)  # 52 per direction: 6 blocks of 8
    assert nnode.time_blocks(short, 8, 10) == 6


# --- the command end to end ------------------------------------------------------------------------


def test_gap_command_on_a_simulated_four_node_null(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A four-node asil run written as CSVs, imported with `uwbcal import asil`, diagnosed with
    `uwbcal gap` and its default scenario: the believed world is built, said, and agrees."""
    from uwbcal.cli import main

    rng = np.random.default_rng(5)
    sched = blind_nnode.round_robin_schedule(_truth(), 40.0, rng, DIST)
    from uwbcal import vectorsim
    from uwbcal.physics.world import World

    sc = _truth()
    for sid in sc.station_ids:
        sc = sc.with_station(sid, counter_offset_units=0)
    rec, _ = vectorsim.run_triplets(World(sc, 424242), sched)
    run = tmp_path / "run"
    blind_nnode.write_asil_run(rec, {1: 0, 2: 1, 3: 2, 4: 3}, run, DIST)
    db = tmp_path / "four.db"
    assert main(["import", "asil", str(run), "--out", str(db)]) == 0
    capsys.readouterr()
    args = ["gap", str(db), "--seeds", "12", "--signature-seeds", "2", "--ensembles", "1", "--jobs", "1"]
    assert main([*args, "--json", "--quiet", "--write-scenario", str(tmp_path / "fitted.toml")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["verdict"] == "no significant gap", out["summary"]
    assert "2 added stations" in out["scenario"]
    added = out["stations_added"]["added"]
    assert [a["real_station"] for a in added] == [2, 3]
    assert np.allclose([a["ppm"] for a in added], [1.5, 2.4], atol=0.01)  # the true offsets, from the rates
    every = {f"{a}->{b}" for a in range(4) for b in range(4) if a != b}
    assert {c["label"] for c in out["cells"] if c["regime"] == "direction"} == every
    assert load_scenario(tmp_path / "fitted.toml").station_ids == [1, 2, 3, 4]
    assert main([*args, "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "stations added" in text.splitlines()[1] and "added station 4 (real 3)" in text


def test_gap_command_refuses_a_session_without_a_testable_direction(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from uwbcal.cli import main

    db = tmp_path / "a4.db"
    assert main(["import", "asil", str(ASIL4), "--out", str(db)]) == 0
    capsys.readouterr()
    rc = main(["gap", str(db), "--quiet"])
    err = capsys.readouterr().err
    assert rc != 0 and "every one of its 12 directions has fewer than 20" in err


# --- checks on simulated four-node sessions (not self-referential: the departures' own forms) ------


@pytest.mark.parametrize("seed", [0, 1])
def test_null_four_node_session_has_no_gap(seed: int) -> None:
    real = blind_nnode.make_session(_truth(), DIST, 40.0, seed)
    d, world = _diagnose(real, seed)
    assert d.verdict == "no significant gap", [(c.observable, c.label, c.z) for c in d.significant]
    assert len(world.added) == 2 and d.cells


def test_a_noisier_transmitter_is_named_not_the_receivers() -> None:
    """Station 3 (asil node 2) transmits with Student-t jitter of 80 ps SD added to every stamp of
    its messages (departures.extra_jitter, tx_station): about 10 x the believed 8 ps per stamp."""
    real = blind_nnode.make_session(
        _truth(), DIST, 40.0, 2, [lambda r, g: dep.extra_jitter(r, g, 80.0, tx_station=3)]
    )
    d, _ = _diagnose(real, 2)
    named = [n["effect"] for n in d.named]
    assert named[:1] == ["timestamp_noise_tx[3]"], d.summary
    assert not [e for e in named if e.startswith("timestamp_noise[")], d.summary
    assert d.selection_steps[0]["runner_up"]["ci"][0] > 0.0  # beats the best other explanation
    # the fitted TX jitter, 2 ps x scale, is the departure's robust size: a t(5) of SD 80 ps has a
    # normal-consistent MAD of 0.8 x 80 ps
    fitted_ps = 2.0 * d.named[0]["fitted"]
    assert 0.6 * 80.0 < fitted_ps < 1.0 * 80.0, fitted_ps
    assert d.station_noise["separable"] and "station 2 TX" in d.station_noise["named"]


def test_a_noisier_receiver_is_named_not_the_transmitters() -> None:
    real = blind_nnode.make_session(
        _truth(), DIST, 40.0, 2, [lambda r, g: dep.extra_jitter(r, g, 80.0, rx_station=4)]
    )
    d, _ = _diagnose(real, 2)
    named = [n["effect"] for n in d.named]
    assert named[:1] == ["timestamp_noise[4]"], d.summary
    assert not [e for e in named if e.startswith("timestamp_noise_tx")], d.summary
    assert d.station_noise["separable"] and "station 3 RX" in d.station_noise["named"]


# --- the per-station separation from the records alone (gap/stations.py) ---------------------------


@pytest.mark.parametrize(
    ("rx", "tx", "expect"),
    [(None, None, []), (None, 3, ["station 2 TX"]), (4, None, ["station 3 RX"]), (None, 2, ["station 1 TX"])],
)
def test_station_noise_names_the_three_times_noisier_station_and_none_in_a_null(
    rx: int | None, tx: int | None, expect: list[str]
) -> None:
    """18 ps of extra jitter per stamp (3 x the believed 6.4 ps RX + TX, before the unit's rounding):
    the station named is the right one and the right side; a null names none (the old
    excess-over-the-quietest rule named one at every null seed)."""
    from uwbcal.gap import stations

    for seed in (0, 1):
        f: list[blind_nnode.Departure] = []
        if rx is not None or tx is not None:
            f = [lambda r, g: dep.extra_jitter(r, g, 18.0, rx_station=rx, tx_station=tx)]
        real = blind_nnode.make_session(_truth(), DIST, 40.0, seed, f)
        s = stations.station_noise(real, seed=seed)
        rows = s["excess_over_quietest"]
        assert s["named"] == expect, [(r["station"], r["side"], round(r["z"], 1)) for r in rows]
