"""The analyses take the PRF from the session's radio configuration, not an assumed 64 MHz."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from uwbcal import dw1000
from uwbcal.corrections import analysis
from uwbcal.errors import SessionError
from uwbcal.gap import observables as obs


def test_session_prf_from_meta() -> None:
    assert analysis.session_prf_mhz({"radio": {"channel": 5, "prf_mhz": 16}}) == 16
    assert analysis.session_prf_mhz({"radio": {"prf_mhz": 64}}) == 64
    assert analysis.session_prf_mhz({}) == 64  # sessions from before the radio was stored
    # an import whose source does not record the PRF (the ASIL importer writes null)
    assert analysis.session_radio({"radio": {"channel": None, "prf_mhz": None, "data_rate_kbps": None}}) == (
        2, 64, 6810)
    radio = {"channel": 5, "prf_mhz": 16, "data_rate_kbps": 850}
    assert analysis.session_radio({"radio": radio}) == (5, 16, 850)
    with pytest.raises(SessionError, match="prf_mhz"):
        analysis.session_prf_mhz({"radio": {"prf_mhz": 32}})
    with pytest.raises(SessionError, match="channel"):
        analysis.session_radio({"radio": {"channel": 6}})


def test_levels_follow_the_prf() -> None:
    """Same registers, PRF 16 vs 64: the level differs by the two constants A (UM 4.7.2)."""
    rec = {f"cir_pwr{k}": np.array([900, 1000, 1100, 1200]) for k in (1, 2, 3)}
    rec |= {f"rxpacc{k}": np.array([120, 118, 121, 119]) for k in (1, 2, 3)}
    l64 = obs.observables(rec, 64)["rx_level_dbm"]
    l16 = obs.observables(rec, 16)["rx_level_dbm"]
    want = dw1000.RX_LEVEL_A_DBM[64] - dw1000.RX_LEVEL_A_DBM[16]
    np.testing.assert_allclose(l16 - l64, want, rtol=0, atol=1e-9)
    m16 = analysis.measured_level(rec, "2", prf_mhz=16)
    assert m16 is not None
    np.testing.assert_allclose(m16, l16, rtol=0, atol=1e-9)


def test_gap_diagnosis_reads_the_sessions_prf(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A PRF-16 session: `uwbcal gap` computes its RX levels with A for PRF 16 (UM 4.7.2), in the
    real session's observables as in the engine's features and cells, not with the PRF 64 default."""
    import dataclasses

    from uwbcal import vectorsim
    from uwbcal.cli import main
    from uwbcal.gap import engine, validate
    from uwbcal.gap.features import build_space
    from uwbcal.gap.localise import summarise
    from uwbcal.physics.scenario import load_scenario
    from uwbcal.sessions.store import Session

    sc = load_scenario(validate.SCENARIO)
    sc = dataclasses.replace(sc, radio=dataclasses.replace(sc.radio, prf_mhz=16))
    sched = validate.validation_schedule(sc, per_step=30, steps=4)
    db = tmp_path / "prf16.db"
    vectorsim.simulate_session(sc, sched, db, seed=5)
    with Session.open(db, readonly=True) as s:
        assert analysis.session_prf_mhz(s.meta) == 16
        real = s.read("triplets")
    l16 = obs.observables(real, 16)["rx_level_dbm"]
    l64 = obs.observables(real, 64)["rx_level_dbm"]
    shift = dw1000.RX_LEVEL_A_DBM[16] - dw1000.RX_LEVEL_A_DBM[64]  # level = ... - A
    np.testing.assert_allclose(l64 - l16, shift, rtol=0, atol=1e-9)

    # the engine's steps follow Config.prf_mhz: features and summaries of the same records
    cfg16 = engine.Config(prf_mhz=16)
    names = list(obs.observables(real, 16))
    sp16, sp64 = build_space(real, cfg16, names), build_space(real, engine.Config(prf_mhz=64), names)
    assert sp16.prf_mhz == 16
    i = names.index("rx_level_dbm")
    mean = (sp16.feat_obs == i) & (sp16.feat_stat == 0)
    f16, f64 = sp16.features(real, 8)[mean], sp64.features(real, 8)[mean]
    ok = np.isfinite(f16)
    assert ok.any()
    np.testing.assert_allclose(f64[ok] - f16[ok], shift, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(summarise(real, sp16.t_edges, None, 16)[0]["rx_level_dbm"], l16)

    # the command takes the PRF from the session's meta (and the scenario from it): its cells
    # report PRF-16 levels
    rc = main(["gap", str(db), "--seeds", "4", "--jobs", "1", "--ensembles", "1", "--json", "--quiet"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["settings"]["prf_mhz"] == 16
    (cell,) = [c for c in out["cells"] if c["observable"] == "rx_level_dbm" and c["regime"] == "all"]
    assert cell["n_real"] == np.count_nonzero(np.isfinite(l16))
    assert abs(cell["real_mean"] - float(np.nanmean(l16))) < 1e-6
    assert abs(cell["real_mean"] - float(np.nanmean(l64))) > 1.0
