"""The analyses take the PRF from the session's radio configuration, not an assumed 64 MHz."""

from __future__ import annotations

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
