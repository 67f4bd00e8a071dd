"""Comparing floats against a stored file, across machines: a tolerance in units in the last
place (ULP), never bit for bit.

numpy's and libm's exp/log/log10/sin/tanh/pow take different code paths on other CPUs (SIMD
widths, libm versions) and may round the last bit differently; a result stored on one machine
is then 1-2 ULP off on another (seen on an AMD EPYC against the recording machine). Integers,
strings, booleans and None must still be identical. Within one process the comparisons stay
exact (same code, same machine): this is only for stored files. See docs/CONTRIBUTING.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Default float tolerance against a stored file, ULPs. tests/unit/test_world_golden.py measures
#: the need: every transcendental result moved up to 1 ULP moves the physics outputs by <= 13 ULP.
STORED_ULPS = 32


def ulp_mismatch(want: np.ndarray, got: np.ndarray, ulps: int = STORED_ULPS) -> str | None:
    """Why ``got`` does not match the stored ``want``, or None when it does.

    Non-float arrays must be identical. Float arrays must have NaN and infinities in the same
    places and every finite element within ``ulps`` ULPs of the larger of the element's own
    magnitude and the array's largest finite magnitude (an element that comes out of a
    cancellation, a difference of two large numbers, carries the large numbers' ULPs)."""
    if want.dtype != got.dtype or want.shape != got.shape:
        return f"dtype/shape {want.dtype}{want.shape} -> {got.dtype}{got.shape}"
    if want.dtype.kind != "f":
        return None if np.array_equal(want, got) else "not identical"
    fw, fg = np.isfinite(want), np.isfinite(got)
    if not np.array_equal(fw, fg) or not np.array_equal(want[~fw], got[~fg], equal_nan=True):
        return "NaN/inf in other places"
    if not fw.any():
        return None
    w, g = want[fw], got[fg]
    scale = np.maximum(np.maximum(np.abs(w), np.abs(g)), np.max(np.abs(w)))
    diff = np.abs(w - g)
    limit = ulps * np.spacing(scale)
    if np.all(diff <= limit):
        return None
    worst = int(np.argmax(diff / limit))
    return f"{float(diff[worst] / np.spacing(scale[worst])):.3g} ULP at element {worst} (limit {ulps})"


def json_mismatch(want: Any, got: Any, ulps: int = STORED_ULPS, path: str = "$") -> str | None:
    """Where two JSON-like values differ, or None: same structure, same keys, identical
    non-floats, each float within ``ulps`` ULPs of the stored one (its own magnitude)."""
    if isinstance(want, float) or isinstance(got, float):
        if not (isinstance(want, float) and isinstance(got, float)):
            return f"{path}: {want!r} -> {got!r}"
        why = ulp_mismatch(np.array([want]), np.array([got]), ulps)
        return None if why is None else f"{path}: {want!r} -> {got!r} ({why})"
    if isinstance(want, dict) and isinstance(got, dict):
        if sorted(want) != sorted(got):
            return f"{path}: keys {sorted(want)} -> {sorted(got)}"
        for k in want:
            why = json_mismatch(want[k], got[k], ulps, f"{path}.{k}")
            if why:
                return why
        return None
    if isinstance(want, list) and isinstance(got, list):
        if len(want) != len(got):
            return f"{path}: length {len(want)} -> {len(got)}"
        for i, (a, b) in enumerate(zip(want, got, strict=True)):
            why = json_mismatch(a, b, ulps, f"{path}[{i}]")
            if why:
                return why
        return None
    return None if type(want) is type(got) and want == got else f"{path}: {want!r} -> {got!r}"
