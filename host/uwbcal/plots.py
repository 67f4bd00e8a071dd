"""Figures of `uwbcal analyze` and `uwbcal paper` (PNG, matplotlib Agg backend).

Every figure states the theoretical noise floor it is compared with (a standard error of a mean,
from the timestamp noise or from the data's own scatter) in its title or a note. Inputs are the
plain dicts and objects of :mod:`uwbcal.corrections.analysis`; units: metres, seconds, dBm.
matplotlib is imported inside the functions so importing this module stays cheap.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from uwbcal import dw1000
from uwbcal.corrections.power import PowerCalibration
from uwbcal.dw1000 import FloatArray


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _plt().close(fig)
    return path


def _window(x: FloatArray, n: int) -> FloatArray:
    """Means of consecutive windows of n values (the paper's filtered points)."""
    k = max(1, x.size // max(n, 1))
    return np.asarray([np.mean(c) for c in np.array_split(x, k)], dtype=np.float64)


def plot_drift(series: Mapping[str, FloatArray], path: Path, floor_m: float, window: int = 200,
               title: str = "Clock drift correction (eq. 1)") -> Path:
    """C_12 before and C'_12 after eq. 1 (and with the carrier integrator), window means, m."""
    plt = _plt()
    has_ci = "carrier_integrator_m" in series
    fig, axes = plt.subplots(1, 3 if has_ci else 2, figsize=(15 if has_ci else 11, 4))
    t = _window(series["t_s"], window)
    axes[0].plot(t, _window(series["uncorrected_m"], window), ".", ms=3)
    axes[0].set_title("before: C_12 (drift error)")
    axes[0].set_xlabel("time, s")
    axes[0].set_ylabel("error, m")
    axes[1].plot(t, _window(series["corrected_m"], window), ".", ms=3, label="eq. 1 (C'_12)")
    axes[1].axhline(floor_m, color="k", ls=":", lw=0.8, label=f"+-floor {floor_m:.1e} m")
    axes[1].axhline(-floor_m, color="k", ls=":", lw=0.8)
    axes[1].axhline(0.0, color="k", lw=0.5)
    axes[1].set_title(f"after eq. 1, means of {window}; floor sigma/sqrt({window}) = {floor_m:.1e} m",
                      fontsize=9)
    axes[1].set_xlabel("time, s")
    axes[1].legend(fontsize=8)
    if has_ci:
        axes[2].plot(t, _window(series["carrier_integrator_m"], window), ".", ms=3, color="C1")
        axes[2].axhline(0.0, color="k", lw=0.5)
        axes[2].set_title("carrier-integrator correction (baseline)", fontsize=9)
        axes[2].set_xlabel("time, s")
    fig.suptitle(title)
    return _save(fig, path)


def plot_carint_jump(series: Mapping[str, FloatArray], path: Path, floor_ppm: float,
                     window: int = 200) -> Path:
    """Measured RX level and carrier-integrator offset (window means) when only TX power changes."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    t = _window(series["t_s"], window)
    if "measured1_dbm" in series:
        axes[0].plot(t, _window(series["measured1_dbm"], window), ".", ms=3)
    axes[0].set_title("filtered RX level")
    axes[0].set_xlabel("time, s")
    axes[0].set_ylabel("dBm")
    axes[1].plot(t, _window(series["car_int_ppm"], window), ".", ms=3, label="carrier integrator")
    if "drift_ppm" in series:
        axes[1].plot(t, _window(series["drift_ppm"], window), ".", ms=3, label="eq. 1 (C_13 / dT_13)")
    axes[1].set_title(f"clock offset, ppm; floor (sigma/sqrt({window})) {floor_ppm:.1e} ppm")
    axes[1].set_xlabel("time, s")
    axes[1].legend(fontsize=8)
    fig.suptitle("Carrier integrator against signal power")
    return _save(fig, path)


def plot_power(cals: Sequence[tuple[str, PowerCalibration]], path: Path, title: str,
               truth: Sequence[tuple[FloatArray, FloatArray]] | None = None) -> Path:
    """Per-step P1/P2 measured level and the timestamp-error curve (m) against measured power.

    The floor stated is the median per-step standard error of the mean of C'_12.
    """
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    floors = []
    for i, (label, cal) in enumerate(cals):
        st = cal.steps
        k = [s.step for s in st]
        axes[0].plot(k, [s.measured_dbm for s in st], ".-", ms=3, color=f"C{2 * i}", label=f"P2 {label}")
        axes[0].plot(k, [s.measured_p1_dbm for s in st], "--", lw=0.8, color=f"C{2 * i + 1}",
                     label=f"P1/P3 {label}")
        c = cal.curve
        axes[1].plot(c.measured_dbm, np.asarray(c.error_s) * dw1000.C_LIGHT, ".-", ms=3, color=f"C{2 * i}",
                     label=label)
        floors.append(np.nanmedian([s.error_sem_s for s in st]) * dw1000.C_LIGHT)
        if truth is not None and i < len(truth):
            axes[1].plot(truth[i][0], truth[i][1], "k:", lw=0.8, label=f"truth {label}" if i == 0 else None)
    if cals:
        thr = cals[0][1].threshold_dbm
        axes[0].axhline(thr, color="r", lw=0.6, ls=":", label=f"{thr:g} dBm: level estimate right below")
        axes[1].axvline(thr, color="r", lw=0.6, ls=":", label=f"{thr:g} dBm")
    axes[0].set_xlabel("gain step of P2 (index)")
    axes[0].set_ylabel("measured RX level, dBm")
    axes[0].legend(fontsize=7)
    axes[1].set_xlabel("measured RX level of P2, dBm")
    axes[1].set_ylabel("timestamp error C'_12 * c, m (unknown constant)")
    axes[1].set_title(f"noise floor per step (SEM) {float(np.nanmedian(floors)):.1e} m")
    axes[1].legend(fontsize=7)
    fig.suptitle(title)
    return _save(fig, path)


def plot_measured_vs_real(cals: Sequence[tuple[str, PowerCalibration]], path: Path,
                          truth: Sequence[tuple[FloatArray, FloatArray]] | None = None) -> Path:
    """Measured against estimated real RX power, with the fitted line and the identity."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for i, (label, cal) in enumerate(cals):
        real = np.array([s.real_dbm for s in cal.steps])
        meas = np.array([s.measured_dbm for s in cal.steps])
        axes[0].plot(real, meas, ".", ms=4, color=f"C{i}", label=label)
        err_m = np.asarray([s.error_s for s in cal.steps]) * dw1000.C_LIGHT
        axes[1].plot(real, err_m, ".-", ms=3, color=f"C{i}", label=label)
        if truth is not None and i < len(truth):
            axes[0].plot(truth[i][0], truth[i][1], "k:", lw=0.8)
    lo, hi = axes[0].get_xlim()
    axes[0].plot([lo, hi], [lo, hi], "k--", lw=0.6, label="measured = real")
    cal0 = cals[0][1]
    axes[0].axhline(cal0.threshold_dbm, color="r", lw=0.6, ls=":",
                    label=f"fit below {cal0.threshold_dbm} dBm")
    axes[0].set_xlabel("real RX power (estimated), dBm")
    axes[0].set_ylabel("measured RX level, dBm")
    floor = float(np.nanmedian([s.measured_sem_db for s in cal0.steps]))
    axes[0].set_title(f"fit slope {cal0.slope:.3f}, offset {cal0.offset_dbm:.2f} dBm; "
                      f"floor (SEM per step) {floor:.3f} dB")
    axes[0].legend(fontsize=7)
    axes[1].set_xlabel("real RX power, dBm")
    axes[1].set_ylabel("timestamp error * c, m")
    axes[1].set_title("signal power error curve")
    axes[1].legend(fontsize=7)
    fig.suptitle("Measured vs real signal power")
    return _save(fig, path)


def plot_twr(result: Mapping[str, Any], path: Path, floor_m: float,
             methods: Sequence[str] = ("paper", "paper_no_power", "paper_no_drift", "ds", "ss_carint_aps011",
                                       "station")
             ) -> Path:
    """Range error after each method's Z (m) against distance (m), mean +- std per distance, one
    colour per method (the paper's error-vs-distance figure). With one distance only, the spread
    per method is drawn as bars over the method names instead (no fake distance axis)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    shown = [(n, result["methods"][n]) for n in methods if n in result["methods"]]
    dists = sorted({p["distance_m"] for _, m in shown for p in m["per_distance"]})
    if len(dists) <= 1:
        names = [n for n, _ in shown]
        std = [m["std_all_m"] for _, m in shown]
        ax.bar(range(len(names)), std, color=[f"C{i}" for i in range(len(names))])
        ax.set_xticks(range(len(names)), names, rotation=20, fontsize=8)
        ax.axhline(floor_m, color="k", ls=":", lw=0.8, label=f"single-exchange floor {floor_m * 100:.2f} cm")
        ax.set_ylabel("std of the range error, m")
        ax.set_title(f"TWR error spread per method at {dists[0] if dists else '?'} m (one distance)")
        ax.legend(fontsize=7)
        return _save(fig, path)
    span = max(dists) - min(dists)
    for i, (name, m) in enumerate(shown):
        per = m["per_distance"]
        d = np.array([p["distance_m"] for p in per]) + (i - len(shown) / 2) * 0.006 * span
        ax.errorbar(d, [p["mean_error_m"] for p in per], yerr=[p["std_error_m"] for p in per], fmt=".-",
                    ms=4, capsize=2, lw=0.8, color=f"C{i}",
                    label=f"{name} (std {m['std_all_m'] * 100:.1f} cm)")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("true distance, m (methods offset slightly to be seen)")
    ax.set_ylabel("range error after Z, m")
    ax.set_title(f"TWR error; Z at {result['z_distance_m']} m; "
                 f"single-exchange noise floor {floor_m * 100:.2f} cm")
    ax.legend(fontsize=7)
    return _save(fig, path)
