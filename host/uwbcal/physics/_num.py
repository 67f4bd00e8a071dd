"""Scalar-or-array primitives: one formula serves both simulated paths bit for bit.

The physics (:mod:`uwbcal.physics.models`, :mod:`uwbcal.physics.world`) is written once, in
expressions that take either a Python float (the per-frame path of the medium: one frame, no
array overhead) or a float64 numpy array (the vectorised simulator). Both give identical bits
for the same inputs and seed because:

- ``+ - * /`` and comparisons are the same IEEE-754 double operations on a float and on a
  float64 array element (no fused multiply-add on either side), evaluated in the same order;
- transcendental functions (exp, tanh, log10, logaddexp, power) always go through the numpy
  ufunc, also for a float: numpy's SIMD kernels (SVML on AVX-512) and the C library behind
  the ``math`` module differ in the last ulp. A variable exponent is :func:`power`, never
  ``**`` (Python's ``**`` on floats is the C library's pow); ``x**2`` is written ``x * x``;
- exact operations (floor, rint, sqrt, min/max, casts to int) use builtins/``math`` on floats,
  falling back to numpy for non-finite values so that even those behave like the array path;
- random draws without a size (``size=None``) consume the same bits of a
  :class:`numpy.random.Generator` as the same draw with size ``(1,)``.

A *shape* ``n`` is ``None`` for a float, else the array shape. tests/unit/test_world_golden.py
checks the identity on recorded outputs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeAlias

import numpy as np
import numpy.typing as npt

#: A Python float (per-frame path) or a float64 array (vectorised path).
Num: TypeAlias = Any
#: None for a float, else the array shape.
Shape: TypeAlias = "tuple[int, ...] | None"

_INT64_LIMIT = 9.2e18  # |x| below this casts to int64 exactly as numpy does (truncation)


# -- conversions at the API boundary ------------------------------------------------------
def one(x: Any) -> tuple[float, tuple[int, ...]] | None:
    """(the value as a float, the input's shape) if ``x`` holds exactly one number (Python or
    numpy scalar, 0-d or one-element array or sequence), else None."""
    if isinstance(x, float):  # also np.float64
        return float(x), ()
    if isinstance(x, np.ndarray):
        return (float(x.flat[0]), x.shape) if x.size == 1 else None
    if isinstance(x, int) and not isinstance(x, bool):
        return float(x), ()
    if isinstance(x, (list, tuple)):
        if len(x) == 1 and isinstance(x[0], (int, float, np.number)) and not isinstance(x[0], bool):
            return float(x[0]), (1,)
        return None
    if isinstance(x, np.number):
        return float(x), ()
    return None


def one_int(x: Any) -> tuple[int, tuple[int, ...]] | None:
    """Like :func:`one` for integers: (the value cast to int64 as numpy does, shape) or None."""
    if isinstance(x, int) and not isinstance(x, bool):
        return x, ()
    if isinstance(x, np.ndarray):
        return (int(x.astype(np.int64).flat[0]), x.shape) if x.size == 1 else None
    if isinstance(x, (list, tuple)):
        if len(x) == 1 and isinstance(x[0], (int, np.integer)) and not isinstance(x[0], bool):
            return int(x[0]), (1,)
        return None
    if isinstance(x, np.integer):
        return int(x), ()
    return None


def arr(v: Any, shape: tuple[int, ...]) -> npt.NDArray[Any]:
    """A per-frame value back as an array of ``shape`` (float64, int64 or bool by its type)."""
    if shape == (1,):
        return np.array([v])
    if shape == ():
        return np.asarray(v)
    return np.full(shape, v)


# -- array-only operations with a float form ----------------------------------------------
def full(n: Shape, v: float) -> Num:
    """``v`` (float) or an array of shape ``n`` filled with it."""
    return v if n is None else np.full(n, v)


def full_int(n: Shape, v: int) -> Any:
    """``v`` (int) or an int64 array of shape ``n`` filled with it."""
    return v if n is None else np.full(n, v, dtype=np.int64)


def copy(x: Num) -> Num:
    """An independent copy (floats are immutable)."""
    return x if isinstance(x, float) else x.copy()


def maximum0(x: Num) -> Num:
    """np.maximum(x, 0.0)."""
    if isinstance(x, float):
        return x if (x >= 0.0 or x != x) else 0.0
    return np.maximum(x, 0.0)


def minimum0(x: Num) -> Num:
    """np.minimum(x, 0.0)."""
    if isinstance(x, float):
        return x if (x <= 0.0 or x != x) else 0.0
    return np.minimum(x, 0.0)


def any_negative(x: Num) -> bool:
    """Whether any value is < 0."""
    if isinstance(x, float):
        return x < 0.0
    return bool(x.size) and float(x.min()) < 0.0


def all_below(x: Num, limit: float) -> bool:
    """Whether max |x| < limit (True for an empty array; False if a value is NaN)."""
    if isinstance(x, float):
        return abs(x) < limit
    return not x.size or float(np.max(np.abs(x))) < limit


def where(cond: Any, a: Num, b: Num) -> Num:
    """np.where(cond, a, b)."""
    if isinstance(cond, (bool, np.bool_)):
        return a if cond else b
    return np.where(cond, a, b)


def isnan_to_inf(x: Num) -> Num:
    """NaN replaced by +inf."""
    if isinstance(x, float):
        return math.inf if x != x else x
    return np.where(np.isnan(x), np.inf, x)


# -- exact roundings and casts ------------------------------------------------------------
def floor(x: Num) -> Num:
    """np.floor(x)."""
    if isinstance(x, float):
        return float(math.floor(x)) if x - x == 0.0 else float(np.floor(x))
    return np.floor(x)


def rint(x: Num) -> Num:
    """np.rint(x) (round half to even)."""
    if isinstance(x, float):
        return float(round(x)) if x - x == 0.0 else float(np.rint(x))
    return np.rint(x)


def clip_(x: Num, lo: float, hi: float) -> Num:
    """np.clip(x, lo, hi), in place for an array."""
    if isinstance(x, float):
        if x != x:
            return float(np.clip(x, lo, hi))
        return float(lo) if x < lo else float(hi) if x > hi else x
    return np.clip(x, lo, hi, out=x)


def minimum_(x: Num, hi: float) -> Num:
    """np.minimum(x, hi), in place for an array."""
    if isinstance(x, float):
        return x if (x <= hi or x != x) else float(hi)
    return np.minimum(x, hi, out=x)


def to_int(x: Num) -> Any:
    """x.astype(np.int64) (truncation toward zero); an int for a float."""
    if isinstance(x, float):
        if -_INT64_LIMIT < x < _INT64_LIMIT:
            return int(x)
        return int(np.array([x]).astype(np.int64)[0])  # NaN/inf/huge: numpy's cast, as the arrays
    return x.astype(np.int64)


def max_int(k: Any) -> int:
    """Largest value of int(s) ``k`` (0 for an empty array)."""
    if isinstance(k, int):
        return k
    return int(k.max()) if k.size else 0


def take(table: Any, k: Any) -> Num:
    """table[k]: a float for an int index, else an array."""
    return table.item(k) if isinstance(k, int) else table[k]


# -- transcendental functions: always the numpy ufunc -------------------------------------
def exp(x: Num) -> Num:
    """np.exp(x)."""
    return float(np.exp(x)) if isinstance(x, float) else np.exp(x)


def exp_quiet(x: Num) -> Num:
    """np.exp(x) without overflow/invalid warnings."""
    if isinstance(x, float) and x < 700.0:  # cannot overflow (NaN is not < 700)
        return float(np.exp(x))
    with np.errstate(over="ignore", invalid="ignore"):
        r = np.exp(x)
    return float(r) if isinstance(x, float) else r


def expm1(x: Num) -> Num:
    """np.expm1(x)."""
    return float(np.expm1(x)) if isinstance(x, float) else np.expm1(x)


def tanh(x: Num) -> Num:
    """np.tanh(x)."""
    return float(np.tanh(x)) if isinstance(x, float) else np.tanh(x)


def log10(x: Num) -> Num:
    """np.log10(x)."""
    return float(np.log10(x)) if isinstance(x, float) else np.log10(x)


def logaddexp0(x: Num) -> Num:
    """np.logaddexp(0.0, x) = ln(1 + exp(x))."""
    return float(np.logaddexp(0.0, x)) if isinstance(x, float) else np.logaddexp(0.0, x)


def power(base: float, x: Num) -> Num:
    """np.power(base, x) (numpy's kernel, also for a float exponent)."""
    return float(np.power(base, x)) if isinstance(x, float) else np.power(base, x)


def sqrt(x: Num) -> Num:
    """np.sqrt(x) (correctly rounded on both sides)."""
    if isinstance(x, float):
        return math.sqrt(x) if x >= 0.0 else float(np.sqrt(x))
    return np.sqrt(x)


# -- random draws (size None consumes the same bits as size (1,)) ------------------------
def normal(rng: np.random.Generator, n: Shape) -> Num:
    """Standard normal draw(s)."""
    return rng.standard_normal() if n is None else rng.standard_normal(n)


def uniform(rng: np.random.Generator, n: Shape) -> Num:
    """Uniform [0, 1) draw(s)."""
    return rng.random() if n is None else rng.random(n)


def exponential(rng: np.random.Generator, scale: float, n: Shape) -> Num:
    """Exponential draw(s) of mean ``scale``."""
    return rng.exponential(scale) if n is None else rng.exponential(scale, n)


def gamma(rng: np.random.Generator, shape: float, scale: float, n: Shape) -> Num:
    """Gamma draw(s) of shape ``shape`` and scale ``scale`` (mean shape * scale)."""
    return rng.gamma(shape, scale) if n is None else rng.gamma(shape, scale, n)


def integers(rng: np.random.Generator, low: int, high: int, n: Shape) -> Any:
    """Integer draw(s) in [low, high) (int64)."""
    return int(rng.integers(low, high)) if n is None else rng.integers(low, high, n)


def floats(x: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """``x`` as a float64 array (no copy when it already is one)."""
    return np.asarray(x, dtype=np.float64)


Arrays3 = tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]


def eval3(fn: Callable[[Num], tuple[Num, Num, Num]], x: npt.ArrayLike) -> Arrays3:
    """``fn`` (written once for a float or an array) at ``x``, its three results as arrays of
    ``x``'s shape: on a Python float when ``x`` holds one value (the per-frame path), else on
    the float64 array."""
    o = one(x)
    if o is not None:
        a, b, c = fn(o[0])
        return arr(a, o[1]), arr(b, o[1]), arr(c, o[1])
    a, b, c = fn(floats(x))
    return np.asarray(a), np.asarray(b), np.asarray(c)
