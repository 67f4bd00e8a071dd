"""The per-level map of the reported RX level (gap/free.py: level_map): what it moves, and whether
a map fitted by quantiles makes the believed levels look like a recording's, for compressions of
other forms than the one it was first built for (a hard knee inside a power step)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy.stats import ks_2samp
from uwbcal.gap import free
from uwbcal.gap import observables as obs_mod


def _sweep(seed: int, per_step: int = 300) -> dict[str, Any]:
    from gap_sweep import sweep

    return sweep(seed, per_step)


def _with_levels(rec: dict[str, Any], new: dict[int, np.ndarray]) -> dict[str, Any]:
    """Records whose reported levels of messages k are ``new[k]`` (dBm), through CIR_PWR."""
    out = dict(rec)
    old = obs_mod.levels(rec)
    for k, lv in new.items():
        c = np.asarray(rec[f"cir_pwr{k}"], np.float64) * 10.0 ** ((lv - old[k]) / 10.0)
        out[f"cir_pwr{k}"] = np.maximum(np.rint(c), 1).astype(np.asarray(rec[f"cir_pwr{k}"]).dtype)
    return out


# Compressions of the reported level written here, apart from the blind generator's hard knee and
# the catalogue's softplus knee: the map must not depend on the form
def _hard_knee(lv: np.ndarray, knee: float) -> np.ndarray:
    return np.where(lv > knee, knee + 0.35 * (lv - knee), lv)


def _tanh_sag(lv: np.ndarray, knee: float) -> np.ndarray:
    return lv - 0.9 * (1.0 + np.tanh((lv - knee) / 1.2))


def _two_slopes(lv: np.ndarray, knee: float) -> np.ndarray:
    lo = np.where(lv > knee - 6.0, knee - 6.0 + 0.8 * (lv - knee + 6.0), lv)
    return np.where(lv > knee, knee - 6.0 + 0.8 * 6.0 + 0.4 * (lv - knee), lo)


def _fit(real: dict[str, Any], sims: list[dict[str, Any]]) -> Any:
    lv_real = obs_mod.observables(real)["rx_level_dbm"]
    lv_sims = np.stack([obs_mod.observables(s)["rx_level_dbm"] for s in sims])
    return free.level_map(
        lv_real, lv_sims, np.asarray(real["rx_station"], np.int64), np.asarray(real["step"], np.int64)
    )


def _worst_step_p(a: dict[str, Any], b: dict[str, Any], obs: str = "rx_level_dbm") -> float:
    """The smallest two-sample KS p-value over the power steps of observable ``obs``."""
    x, y = obs_mod.observables(a)[obs], obs_mod.observables(b)[obs]
    step = np.asarray(a["step"])
    return min(float(ks_2samp(x[step == k], y[step == k]).pvalue) for k in np.unique(step))


@pytest.mark.parametrize("form", [_hard_knee, _tanh_sag, _two_slopes])
def test_a_fitted_map_makes_the_believed_levels_look_like_the_recordings(form: Any) -> None:
    """Fitted on some simulated seeds against a compressed "recording", the map applied to a seed it
    has not seen gives every power step's P2 level and the P3 - P1 level the recording's
    distribution (two-sample KS, smallest p over the steps); without the map the compressed steps
    differ. The knee sits inside the sweep's levels, so one step straddles it."""
    sims = [_sweep(s) for s in (11, 12, 13, 14)]
    truth = _sweep(21)
    lv = obs_mod.levels(truth)
    knee = float(np.quantile(lv[2][np.isfinite(lv[2])], 0.55))
    real = _with_levels(truth, {k: form(lv[k], knee) for k in (1, 2, 3)})
    cand = _fit(real, sims)
    assert cand is not None and cand.effect == "rx_power_estimate"
    fresh = _sweep(31)
    mapped = free.apply(fresh, dict(cand.variant(1.0)), seed=0)
    assert _worst_step_p(fresh, real) < 1e-6  # the departure is there to be found
    assert _worst_step_p(mapped, real) > 1e-3
    assert _worst_step_p(mapped, real, "p13_level_db") > 1e-3


def test_a_map_fitted_where_nothing_departs_moves_levels_by_little() -> None:
    """No departure: the fitted map's change stays within a few quantile standard errors of zero
    (level noise about 0.2 dB per record, 300 records a step: a median's SE is about 0.015 dB)."""
    cand = _fit(_sweep(21), [_sweep(s) for s in (11, 12, 13, 14)])
    assert cand is not None
    d = np.array([v for _, v in cand.shape])
    assert float(np.median(np.abs(d))) < 0.05
    fresh = _sweep(31)
    a = obs_mod.observables(fresh)["rx_level_dbm"]
    b = obs_mod.observables(free.apply(fresh, dict(cand.variant(1.0)), seed=0))["rx_level_dbm"]
    assert float(np.nanmax(np.abs(b - a))) < 0.15


def test_the_map_moves_every_message_by_its_knots_at_its_level_and_nothing_at_magnitude_zero() -> None:
    rec = _sweep(5, per_step=60)
    rx = int(np.asarray(rec["rx_station"])[0])
    lv = obs_mod.levels(rec)
    lo, hi = float(np.nanmin(lv[2])), float(np.nanmax(lv[2]))
    knots = {f"free:lknot:{rx}:{round(lo * 100)}": 0.0, f"free:lknot:{rx}:{round(hi * 100)}": -2.0}
    at = (round(lo * 100) / 100.0, round(hi * 100) / 100.0)
    out = free.apply(rec, {**knots, free.MAP_KNOB: 0.5}, seed=0)
    new = obs_mod.levels(out)
    for k in (1, 2, 3):
        want = 0.5 * np.interp(lv[k], at, (0.0, -2.0))
        assert np.nanmax(np.abs(new[k] - lv[k] - want)) < 0.02  # CIR_PWR is an integer
    same = free.apply(rec, {**knots, free.MAP_KNOB: 0.0}, seed=0)
    assert all(
        np.array_equal(np.asarray(same[f"cir_pwr{k}"]), np.asarray(rec[f"cir_pwr{k}"])) for k in (1, 2, 3)
    )


def test_the_named_map_is_reported_per_level_in_plain_words() -> None:
    named = free.summarise(
        [
            {
                "effect": "rx_power_estimate",
                "knob": free.MAP_KNOB,
                "shape": [
                    ["free:lknot:1:-8000", 0.0],
                    ["free:lknot:1:-7800", 0.0],
                    ["free:lknot:1:-7600", -1.0],
                ],
                "fitted": 1.0,
                "baseline": 0.0,
                "unit": "",
                "description": "",
                "at_grid_edge": False,
            }
        ]
    )
    assert named[0]["shape"] == []
    assert named[0]["per_level"] == {
        "rx 1 at -80 dBm": 0.0,
        "rx 1 at -79 dBm": 0.0,
        "rx 1 at -78 dBm": 0.0,
        "rx 1 at -77 dBm": -0.5,
        "rx 1 at -76 dBm": -1.0,
    }
    from uwbcal.gap.fitted import plain_name

    assert plain_name(named[0]) == "rx power estimate: " + free.MAP_WORDS
