"""RXPACC_NOSAT: the simulator produces receptions whose RXPACC counts the SFD (RXPACC_NOSAT
equal to it), and the host's correction (the same rule as the station's caltable.c) reads the
true level back; with the effect's default (0) no reception is in that case."""

from __future__ import annotations

import numpy as np
from test_physics import BASE
from uwbcal import dw1000
from uwbcal.corrections import power
from uwbcal.physics import World, parse_scenario


def _receive(frac: float) -> tuple[dict[str, np.ndarray], np.ndarray]:
    sc = parse_scenario(BASE).with_effects(
        enabled={"rx_power_estimate": True},
        params={"rx_power_estimate": {"sfd_in_rxpacc": frac, "noise_db": 0.0}})
    w = World(sc)
    a, b = w.station_ids[:2]
    t = np.arange(400) * 1e-3 + 1.0
    rx = w.receive(a, b, t, np.full(t.size, 0xC0))
    return rx.regs, rx.est_dbm


def test_simulator_produces_the_case_and_the_correction_reads_it() -> None:
    regs, est = _receive(0.5)
    same = regs["rxpacc"] == regs["rxpacc_nosat"]
    assert 0.3 < same.mean() < 0.7
    lvl = power.rx_level_from_registers(regs["cir_pwr"], regs["rxpacc"], regs["rxpacc_nosat"])
    rounding_db = 10 * np.log10(1 + 0.5 / regs["cir_pwr"])  # CIR_PWR is an integer
    assert np.all(np.abs(lvl - est) <= rounding_db + 1e-9)
    raw = dw1000.rx_level_dbm(regs["cir_pwr"], regs["rxpacc"])
    assert np.all(est[same] - raw[same] > 0.2)  # uncorrected: N 5 too large, level too low


def test_default_never_equal() -> None:
    regs, _ = _receive(0.0)
    assert not np.any(regs["rxpacc"] == regs["rxpacc_nosat"])
