"""The lossy proxy's fault model (uwbcal.link.lossy.apply_faults): seeded, per byte, each fault
at its probability; no fault leaves the bytes alone."""

from __future__ import annotations

import numpy as np
from uwbcal.link.lossy import FaultCounts, Faults, apply_faults


def test_no_faults_pass_everything() -> None:
    data = bytes(range(256)) * 40
    c = FaultCounts()
    assert apply_faults(data, Faults(), np.random.default_rng(1), c) == data
    assert (c.passed, c.dropped, c.duplicated, c.corrupted) == (len(data), 0, 0, 0)


def test_each_fault_at_its_rate_and_seeded() -> None:
    data = bytes(200_000)
    f = Faults(drop=1e-2, dup=2e-2, corrupt=3e-2)
    c = FaultCounts()
    out = apply_faults(data, f, np.random.default_rng(7), c)
    for got, p in ((c.dropped, 1e-2), (c.duplicated, 2e-2), (c.corrupted, 3e-2)):
        n = len(data) * p
        assert abs(got - n) < 5 * np.sqrt(n), (got, n)                  # binomial, 5 sigma
    assert len(out) == len(data) - c.dropped + c.duplicated
    assert out.count(0) == len(out) - c.corrupted                       # a corrupted byte always changes
    assert apply_faults(data, f, np.random.default_rng(7), FaultCounts()) == out
