"""Propagation between stations: per-link constants (cable or air, antenna gains, nominal
distance and loss) and the RX power and time of flight of frames. Powers dBm, distances m,
times s.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000
from uwbcal.physics import _num, models
from uwbcal.physics._num import Num, Shape
from uwbcal.physics.records import FloatArray
from uwbcal.physics.world_base import WorldBase


class LinkPath:
    """Constants of the link from one station to another, evaluated once."""

    __slots__ = ("cable", "attenuation_db", "cable_speed", "gains_db", "extra_loss_db", "distance_m",
                 "loss_db", "ref_loss_db", "gap_speed")

    def __init__(self, world: WorldBase, tx: int, rx: int) -> None:
        sc = world.scenario
        link = sc.link(tx, rx)
        pl = world.fx_path
        self.cable = link.kind == "cable"
        self.attenuation_db = link.attenuation_db
        self.cable_speed = link.velocity_factor * dw1000.C_LIGHT
        self.gains_db = sc.station(tx).antenna_gain_dbi + sc.station(rx).antenna_gain_dbi
        self.extra_loss_db = link.extra_loss_db
        #: nominal distance, m, and the path loss there (at ref_distance_m if path_loss is off)
        self.distance_m = sc.distance_m(tx, rx)
        f = world.radio.freq_hz
        self.ref_loss_db: float = models._friis_loss_db(pl.ref_distance_m, f, pl.exponent)
        self.loss_db: float = (
            models._friis_loss_db(self.distance_m, f, pl.exponent) if pl.enabled else self.ref_loss_db
        )
        #: signal speed for the per-frame interference gap
        self.gap_speed = dw1000.C_LIGHT * (link.velocity_factor if self.cable else 1.0)




class Propagation(WorldBase):
    """RX power, time of flight and distance of frames from one station to another."""

    def _path(self, tx: int, rx: int) -> LinkPath:
        p = self._paths.get((tx, rx))
        if p is None:
            p = self._paths[(tx, rx)] = LinkPath(self, tx, rx)
        return p

    def nominal_distance_m(self, a: int, b: int) -> float:
        """Scenario distance between two stations (link length or geometry), m."""
        return self.scenario.distance_m(a, b)

    def _propagation(self, tx: int, rx: int, octet: Any, d: Num | None, n: Shape) -> tuple[Num, Num, Num]:
        """(RX power dBm, time of flight s, distance m) of one frame (``n`` None: ints/floats) or
        of arrays of shape ``n`` (``d`` None: the nominal distance)."""
        hw = self._station(tx)
        path = self._path(tx, rx)
        if n is None:
            p_tx = hw.power_list[octet & 0xFF]
        else:
            p_tx = hw.power_table[octet & 0xFF]
        loss = None
        if d is None:
            d = path.distance_m if n is None else np.broadcast_to(_num.floats(path.distance_m), n)
            loss = path.loss_db
        if path.cable:
            return p_tx - path.attenuation_db, d / path.cable_speed, d
        pl = self.fx_path
        if loss is None:
            f = self.radio.freq_hz
            loss = models._friis_loss_db(d, f, pl.exponent) if pl.enabled else path.ref_loss_db
        return p_tx + path.gains_db - path.extra_loss_db - loss, d / dw1000.C_LIGHT, d

    def propagation(
        self, tx: int, rx: int, gain_octet: npt.ArrayLike, distance_m: npt.ArrayLike | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(true RX power dBm, time of flight s, distance m) of frames from tx to rx.

        ``distance_m`` overrides the scenario geometry (a schedule's tag positions). Air: Friis
        at the channel frequency plus antenna gains minus the link's extra loss; cable: fixed
        attenuation, delay length / (velocity_factor c).
        """
        octet = np.asarray(gain_octet, dtype=np.int64)
        d = None if distance_m is None else _num.floats(distance_m)
        if d is not None and (d.ndim == 0 or d.shape != octet.shape):
            d = np.broadcast_to(d, octet.shape)
        p, tof, dist = self._propagation(tx, rx, octet, d, octet.shape)
        return np.asarray(p), np.asarray(tof), np.asarray(dist, dtype=np.float64)
