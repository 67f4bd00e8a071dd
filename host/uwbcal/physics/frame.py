"""The per-frame API the simulated medium calls: one frame leaving a transmitter, its
reception at each listening station (:meth:`FrameApi.transmit`), with the interference gap
remembered per receiver. Times s.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from uwbcal.physics import _num
from uwbcal.physics.receiver import Receiver
from uwbcal.physics.records import Reception


class FrameApi(Receiver):
    """:meth:`transmit`: one frame, every receiver (scalars, no numpy per frame)."""

    def transmit(
        self,
        tx: int,
        t_true_s: float,
        gain_octet: int,
        receivers: Iterable[int] | None = None,
        distances_m: Mapping[int, float] | None = None,
        rx_antd: Mapping[int, int] | None = None,
    ) -> dict[int, Reception]:
        """One frame leaving ``tx``'s antenna at true time ``t_true_s`` (s) with a TX_POWER octet:
        its reception at each receiver (default every other station).

        Stateful only in the interference gap: the world remembers each receiver's last
        reception time. Pass ``distances_m`` to override geometry per receiver, ``rx_antd`` for
        the LDE_RXANTD register each receiver's firmware programmed.
        """
        out: dict[int, Reception] = {}
        rxs = self._station(tx).others if receivers is None else receivers
        t = float(t_true_s)
        octet = _num.one_int(gain_octet)
        o = octet[0] if octet is not None else int(np.asarray(gain_octet, dtype=np.int64))
        sens = self.radio_sensitivity_dbm
        for rx in rxs:
            d = None if distances_m is None or rx not in distances_m else float(distances_m[rx])
            t_prev = self._last_rx.get(rx)
            gap = None
            if t_prev is not None:
                path = self._path(tx, rx)
                dist = path.distance_m if d is None else d
                gap = t + dist / path.gap_speed - t_prev
            stamp_u, regs, t_arr, rx_dbm, est, bias, err, offset, temp, dist_m, tof = self._rx(
                tx, rx, t, o, d, gap, None if rx_antd is None else rx_antd.get(rx), None, None
            )
            self._last_rx[rx] = t_arr
            out[rx] = Reception(
                rx_station=rx,
                stamp=int(self._wrap(stamp_u)),
                stamp_unwrapped=int(stamp_u),
                regs={k: int(v) for k, v in regs.items()},
                t_arrival_s=float(t_arr),
                rx_dbm=float(rx_dbm),
                est_dbm=float(est),
                bias_s=float(bias),
                error_s=float(err),
                offset_ppm=float(offset),
                temp_c=float(temp),
                distance_m=float(dist_m),
                detected=bool(rx_dbm >= sens),
                extra={"tof_s": float(tof)},
            )
        return out
