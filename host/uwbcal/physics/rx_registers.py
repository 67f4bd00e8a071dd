"""Register synthesis: the RX quality registers (CIR_PWR, RXPACC, FP_AMPL1..3, STD_NOISE,
FP_INDEX, DRX_CAR_INT, RX_TTCKO/RX_TTCKI) a DW1000 would show for a reception, so that the
chip's own formulas (dw1000.rx_level_dbm, car_int_to_ppm) read the model's values back.
"""

from __future__ import annotations

from typing import Any

from uwbcal import dw1000
from uwbcal.physics import _num
from uwbcal.physics._num import Num, Shape
from uwbcal.physics.hardware import StationHardware
from uwbcal.physics.world_base import WorldBase

#: Nominal first-path index (RX_TIME.FP_INDEX integer part) of a clean reception.
FP_INDEX_NOMINAL = 745
#: RXPACC_NOSAT - RXPACC in simulated records when RXPACC does not count the SFD (the
#: rx_power_estimate effect's sfd_in_rxpacc fraction does: then they are equal).
RXPACC_NOSAT_EXTRA = 8


class RegisterSynthesis(WorldBase):
    """The RX quality registers of receptions (:meth:`_registers`)."""

    def _registers(
        self,
        hw: StationHardware,
        est: Num,
        rx_dbm: Num,
        offset_ppm: Num,
        frac_units: Num,
        late: Any,
        n: Shape,
    ) -> dict[str, Any]:
        """RX quality registers for estimated levels ``est`` (dBm): dw1000.rx_level_dbm(CIR_PWR,
        RXPACC) reads ``est`` back (to CIR_PWR's rounding), the first-path power is est - fp_delta_db."""
        radio = self.radio
        rng = self.rng
        rxpacc = radio.preamble_length - 4 - _num.integers(rng, 0, 13, n)
        n2 = rxpacc * rxpacc
        lin = _num.exp((est + self._a_dbm) * self._ln10_10)
        lin *= n2
        cir = _num.clip_(_num.rint(lin * 2.0**-17), 1, 0xFFFF)
        if late is not None:
            s_fp = lin * _num.where(late, self._fp_fac_late, self._fp_fac)
        else:
            s_fp = lin * self._fp_fac
        amp = _num.sqrt(s_fp)
        regs: dict[str, Any] = {
            "cir_pwr": _num.to_int(cir),
            "rxpacc": rxpacc,
            "rxpacc_nosat": rxpacc + RXPACC_NOSAT_EXTRA,
        }
        for i, sw in enumerate(self._fp_sqrt, start=1):
            f = _num.minimum_(_num.rint(amp * sw), 0xFFFF)
            regs[f"fp_ampl{i}"] = _num.to_int(f)
        regs["std_noise"] = _num.full_int(n, self._std_noise)
        regs["fp_index"] = _num.to_int(frac_units * 64) + FP_INDEX_NOMINAL * 64
        # carrier integrator: positive = RX clock fast (manual); car_int_to_ppm reads TX-minus-RX
        c = self.fx_car
        tx_minus_rx = -offset_ppm
        if c.enabled:
            tx_minus_rx = tx_minus_rx + hw.car_k * (rx_dbm - c.ref_dbm)
            if c.noise_ppm:
                tx_minus_rx += _num.normal(rng, n) * c.noise_ppm
        car_f = dw1000.ppm_to_car_int(tx_minus_rx, radio.channel, radio.data_rate_kbps)
        car = _num.rint(float(car_f) if n is None else car_f)
        regs["car_int"] = _num.to_int(_num.clip_(car, -(1 << 20), (1 << 20) - 1))
        tt = _num.clip_(_num.rint(offset_ppm * self._ttck_k), -(1 << 18), (1 << 18) - 1)
        regs["ttcko"] = _num.to_int(tt)
        regs["ttcki"] = _num.full_int(n, self._ttcki)
        if self._sfd_p:  # drawn last and only when on: the other draws keep their order
            counted = _num.uniform(rng, n) < self._sfd_p
            shown = rxpacc + dw1000.RXPACC_SFD_CORR[radio.data_rate_kbps]
            regs["rxpacc"] = _num.where(counted, shown, rxpacc)
            regs["rxpacc_nosat"] = _num.where(counted, shown, rxpacc + RXPACC_NOSAT_EXTRA)
        return regs
