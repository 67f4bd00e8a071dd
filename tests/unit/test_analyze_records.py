"""The record-table layer of the analyses against synthetic, closed-form sessions (no simulator)."""

from __future__ import annotations

import numpy as np
import pytest
from test_corrections import make_exchanges, make_triplets
from uwbcal import dw1000
from uwbcal.corrections import analysis
from uwbcal.corrections.power import PowerCurve

U = dw1000.TIME_UNIT_S


def level_registers(level_dbm: np.ndarray, rxpacc: int = 120) -> tuple[np.ndarray, np.ndarray]:
    c = np.rint(dw1000.cir_pwr_for_level(level_dbm, rxpacc)).astype(np.int64)
    return c, np.full(c.size, rxpacc, dtype=np.int64)


def test_drift_records_by_pair_with_nulls() -> None:
    a = make_triplets(300, eps=5e-6, e1=0.0, e2=0.0, seed=1)
    b = make_triplets(300, eps=-5e-6, e1=0.0, e2=0.0, seed=2)
    rec = {k: np.concatenate([a[k], b[k]]) for k in a}
    rec["tx_station"] = np.repeat([1, 2], 300)
    rec["rx_station"] = np.repeat([2, 1], 300)
    rec["t_s"] = np.concatenate([np.arange(300) * 0.01, np.arange(300) * 0.01])
    rec["car_int1"] = None  # type: ignore[assignment]
    out = analysis.analyze_drift_records(rec)
    assert [(d["tx_station"], d["rx_station"]) for d in out] == [(1, 2), (2, 1)]
    assert out[0]["drift_ppm_mean"] == pytest.approx(5.0, abs=1e-3)
    assert out[1]["drift_ppm_mean"] == pytest.approx(-5.0, abs=1e-3)
    for d in out:
        assert abs(d["corrected"]["mean_m"]) < 0.002
        assert d["carrier_integrator"] is None


def curve_for(station: int, scale: float) -> PowerCurve:
    meas = np.linspace(-95.0, -60.0, 36)
    err = scale * 1e-10 * np.tanh((-78.0 - meas) / 5.0)
    return PowerCurve(tuple(meas), tuple(err), tuple(meas), -60.0, -60.0, rx_station=station)


def test_twr_records_paper_method_recovers_distances() -> None:
    curves = {1: curve_for(1, 1.0), 2: curve_for(2, 1.6)}
    dists = np.array([0.6, 1.2, 2.0, 3.0])
    eps = 4e-6
    recs = []
    for i, d in enumerate(dists):
        lvl = -55.0 - 20 * np.log10(d) - 18.0  # about -73 .. -83 dBm
        e1 = curves[2].error_at_measured(lvl)[()] / U  # tag = station 2 receives M1
        e2 = curves[1].error_at_measured(lvl)[()] / U  # ref = station 1 receives M2
        z_units = 30.0  # hardware offset: every range reads 30 units long
        x = make_exchanges(400, d / dw1000.C_LIGHT / U + z_units, eps, e1, e2, seed=10 + i)
        c, n = level_registers(np.full(400, lvl))
        x.update({"cir_pwr_t1": c, "rxpacc_t1": n, "cir_pwr_r2": c, "rxpacc_r2": n,
                  "ref_station": np.full(400, 1), "tag_station": np.full(400, 2),
                  "distance_m": np.full(400, d),
                  "car_int_r2": np.full(400, np.rint(dw1000.ppm_to_car_int(eps * 1e6)))})
        recs.append(x)
    rg = {k: np.concatenate([r[k] for r in recs]) for k in recs[0]}
    out = analysis.analyze_twr_records(rg, curves, z_distance_m=1.2)
    m = out["methods"]
    assert out["z_distance_m"] == 1.2
    assert set(m) == set(analysis.TWR_METHODS) - {"station"}     # no on-station range in these records
    assert m["paper"]["z_m"] == pytest.approx(-30 * dw1000.METRES_PER_UNIT, abs=0.003)
    assert m["paper"]["rms_of_means_m"] < 0.002
    # without the power correction the per-distance means move by (E1 + E2) / 2 * c (cm level)
    assert m["paper_no_power"]["rms_of_means_m"] > 5 * m["paper"]["rms_of_means_m"]
    assert m["paper_no_power"]["std_of_means_m"] > 0.01
    # ds sees the same power error as paper_no_power
    np.testing.assert_allclose([p["mean_error_m"] for p in m["ds"]["per_distance"]],
                               [p["mean_error_m"] for p in m["paper_no_power"]["per_distance"]], atol=0.002)


def test_twr_records_need_distance() -> None:
    x = make_exchanges(10, 100.0, 1e-6, 0.0, 0.0)
    with pytest.raises(Exception, match="distance"):
        analysis.analyze_twr_records(x)


def test_twr_records_mixed_single_sided_rows() -> None:
    d = 1.5
    x = make_exchanges(300, d / dw1000.C_LIGHT / U, 2e-6, 0.0, 0.0, seed=3)
    x["distance_m"] = np.full(300, d)
    t3r = x["t3r"].copy()
    t3r[::3] = np.iinfo(np.int64).min  # NULL as the store reads it: SS-TWR rows without M3
    x["t3r"] = t3r
    out = analysis.analyze_twr_records(x)
    assert out["methods"]["paper_no_power"]["n"] == 200
    assert out["methods"]["paper_none"]["n"] == 300
    assert abs(out["methods"]["ds"]["per_distance"][0]["mean_error_m"]) < 1e-3


def test_causal_mean_per_group() -> None:
    x = np.array([1.0, 10.0, 3.0, 20.0, 5.0, 30.0])
    g = np.array([0.0, 1.0, 0.0, 1.0, 0.0, 1.0])
    np.testing.assert_allclose(analysis.causal_mean(x, g, 2), [1.0, 10.0, 2.0, 15.0, 4.0, 25.0])
    np.testing.assert_allclose(analysis.causal_mean(x, None, 1), x)
    np.testing.assert_allclose(analysis.causal_mean(x, None, 3)[-1], (5.0 + 20.0 + 30.0) / 3)
