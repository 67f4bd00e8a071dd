"""Delayed transmission: DX_TIME on the 512-unit grid, TX_STAMP = grid + TX_ANTD, and the true
time the frame leaves the antenna (true TX delay, temperature drift, jitter) through the
station's clock. Stamps device units, times s.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from uwbcal.physics import _num
from uwbcal.physics._num import Num, Shape
from uwbcal.physics.records import TxBatch
from uwbcal.physics.world_base import GRID_MASK, TU, WorldBase


class Transmitter(WorldBase):
    """Delayed transmissions (:meth:`delayed_tx`), once for a frame or for arrays."""

    def _tx(self, station: int, dx: Any, tx_antd: int | None, n: Shape) -> tuple[Any, Any, Num, Num, Num]:
        """(TX_STAMP unwrapped, grid units, true departure s, temperature, offset ppm) of delayed
        transmissions at DX_TIME ``dx`` (an int, ``n`` None, or an int64 array of shape ``n``)."""
        hw = self._station(station)
        grid = dx & GRID_MASK if self._grid_on else dx
        antd = hw.tx_antd if tx_antd is None else int(tx_antd)
        stamp_u = grid + antd
        t, y, temp = self.clocks[station]._true_state((grid + hw.tx_true_delay_units) * TU)
        drift = self._delay_drift_s(temp)
        if drift is not None:
            t += drift
        if self._tx_jitter_s:
            # the draw does not depend on the station's scale, so other results stay identical
            sigma = self._tx_jitter_s
            if hw.tx_noise_scale != 1.0:  # this transmitter's jitter scale (Station.tx_noise_scale)
                sigma = sigma * hw.tx_noise_scale
            t += _num.normal(self.rng, n) * sigma
        return stamp_u, grid, t, temp, y

    def delayed_tx(self, station: int, dx_time_units: npt.ArrayLike, tx_antd: int | None = None) -> TxBatch:
        """Delayed transmissions programmed at unwrapped local ``dx_time_units`` (DX_TIME).

        The frame starts at DX_TIME with the low 9 bits cleared (delayed_tx_grid); TX_STAMP is
        that plus TX_ANTD (``tx_antd`` register value, default the station's); the frame leaves
        the antenna at that grid time plus the true TX delay (antenna_delay, temperature) and
        TX jitter (``tx_jitter_ps`` times the station's ``tx_noise_scale``), converted to true
        time through the station's clock.
        """
        one = _num.one_int(dx_time_units)
        if one is not None:
            stamp_u, grid, t, temp, y = self._tx(station, one[0], tx_antd, None)
            sh = one[1]
            return TxBatch(
                stamp=_num.arr(self._wrap(stamp_u), sh),
                stamp_unwrapped=_num.arr(stamp_u, sh),
                grid_units=_num.arr(grid, sh),
                t_true_s=_num.arr(t, sh),
                temp_c=_num.arr(temp, sh),
                offset_ppm=_num.arr(y, sh),
            )
        dx = np.asarray(dx_time_units, dtype=np.int64)
        stamp_u, grid, t, temp, y = self._tx(station, dx, tx_antd, dx.shape)
        return TxBatch(
            stamp=self.wrap(stamp_u),
            stamp_unwrapped=np.asarray(stamp_u),
            grid_units=np.asarray(grid),
            t_true_s=np.asarray(t),
            temp_c=np.asarray(temp),
            offset_ppm=np.asarray(y),
        )
