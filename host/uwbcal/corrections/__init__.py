"""The paper's corrections and the baselines, on plain numpy arrays.

- :mod:`.drift`: eq. 1 clock drift correction of P1/P2/P3 triplets; carrier-integrator baseline.
- :mod:`.power`: power self-calibration (timestamp error against RX power, measured vs real power),
  :class:`~uwbcal.corrections.power.PowerCurve`.
- :mod:`.twr`: the paper's TWR with E1, E2 and Z; single-sided, asymmetric double-sided TWR; APS011.
- :mod:`.zoffset`: Z (or antenna delay) from one known distance.
- :mod:`.analysis`: the same on session record tables (what `uwbcal analyze` runs).
"""
