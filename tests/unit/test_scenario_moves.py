"""Scenario files script positions over time (``[[moves]]``): parsed, validated with a one-line
error, written back by to_toml, and played by the medium's MediumWorldAdapter as virtual time passes."""

from __future__ import annotations

import pytest
from uwbcal.errors import ScenarioError
from uwbcal.medium.airtime import FrameFormat
from uwbcal.medium.port import TxFrame
from uwbcal.medium.world_adapter import MediumWorldAdapter
from uwbcal.physics.scenario import load_scenario, parse_scenario

MOVES = """
[[moves]]
t_s = 20.0
station = 2
position_m = [4.0, 0.0, 1.0]

[[moves]]
t_s = 10.0
station = 2
position_m = [1.0, 0.0, 1.0]
"""


def _with_moves(extra: str = MOVES) -> str:
    return load_scenario("two_stations").source + extra


def test_moves_parse_sorted_and_round_trip() -> None:
    sc = parse_scenario(_with_moves())
    assert [(m.t_s, m.position_m[0]) for m in sc.moves] == [(10.0, 1.0), (20.0, 4.0)]
    assert parse_scenario(sc.to_toml()).moves == sc.moves


@pytest.mark.parametrize("bad, msg", [
    ("[[moves]]\nt_s = 1.0\nstation = 9\nposition_m = [0.0, 0.0, 0.0]\n", "not in stations"),
    ("[[moves]]\nt_s = -1.0\nstation = 2\nposition_m = [0.0, 0.0, 0.0]\n", "must be >= 0"),
    ("[[moves]]\nt_s = 1.0\nstation = 2\nposition_m = [0.0, 0.0]\n", "expected \\[x, y, z\\]"),
    ("[[moves]]\nt_s = 1.0\nstation = 2\n", "expected t_s"),
])
def test_bad_moves_are_named(bad: str, msg: str) -> None:
    with pytest.raises(ScenarioError, match=msg):
        parse_scenario(_with_moves("\n" + bad))


def test_medium_plays_the_moves_as_time_passes() -> None:
    w = MediumWorldAdapter(parse_scenario(_with_moves()), seed=1)
    fmt = FrameFormat(length=12, txbr=2, prf_mhz=64, preamble_symbols=128, ranging=True)

    def frame_at(t: float) -> None:
        w.receive(TxFrame(tx_station=1, t_rmarker_s=t, gain_octet=0x1F, fmt=fmt, channel=2, payload=b""),
                  [2], {2: 16436})

    assert w.distance_m(1, 2) == pytest.approx(2.0)
    frame_at(5.0)
    assert w.distance_m(1, 2) == pytest.approx(2.0)
    frame_at(10.5)
    assert w.distance_m(1, 2) == pytest.approx(1.0)
    frame_at(25.0)
    assert w.position_m(2) == (4.0, 0.0, 1.0)
