"""`uwbcal paper`: the paper's experiments re-run in simulation, with figures and one table.

Each experiment simulates sessions with :mod:`uwbcal.vectorsim` on the scenarios
``paper_cable`` / ``paper_antenna`` (scenarios/), analyses the *records* with exactly the code
of `uwbcal analyze` (:mod:`uwbcal.corrections.analysis`), and only then compares with the
simulation truth (truth tables, :meth:`World.power_bias_s`). The result is a list of headline
rows ``{"name", "value", "unit", "paper", "note"}``: ``paper`` is the paper's number where it
gives one (else None), ``note`` says what is compared. Units: m, dB, dBm, ppm, s.

Experiments (paper section in brackets):
- drift: 4000 triplets at 2 ms, ~5.7 ppm apart, during crystal warm-up [clock drift correction];
- carrier integrator: TX gain of all three messages drops half-way [general approach];
- power by cable, 3 dB steps, and by antenna at 1.5 m, 0.5 dB steps [proposed power approach];
- measured vs real power: paper's line through nominal steps, and segment stitching;
- spacing 150 us against 2 ms [short update time];
- repeatability over six restarts, and the difference between two stations [final results];
- TWR over the 11 distances 0.562..3.515 m, 2000 exchanges each, every correction on/off and
  the baselines [two way ranging].
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uwbcal import dw1000, vectorsim
from uwbcal.corrections import analysis
from uwbcal.corrections.drift import noise_floor_m
from uwbcal.corrections.power import PowerCalibration
from uwbcal.dw1000 import FloatArray
from uwbcal.physics import models
from uwbcal.physics.scenario import Scenario, load_scenario
from uwbcal.physics.world import World
from uwbcal.sessions.plan import gain_ladder

C = dw1000.C_LIGHT
#: TWR gain: 9 dB below full so that 0.562 m stays inside the range the 1.5 m calibration
#: sweeps (a curve is only known over the powers it was calibrated at).
TWR_GAIN = dw1000.gain_octet(0, 13)


@dataclass(frozen=True)
class PaperSizes:
    """Run sizes: triplets per drift run / per gain step, restarts, exchanges per distance."""

    drift_triplets: int = 4000
    jump_triplets: int = 2000
    per_step: int = 2000
    antenna_steps: int = 60
    cable_steps: int = 12
    restarts: int = 6
    twr_per_distance: int = 2000

    @classmethod
    def quick(cls) -> PaperSizes:
        """Small runs for tests (same experiments, larger noise)."""
        return cls(drift_triplets=1000, jump_triplets=400, per_step=300, antenna_steps=60, cable_steps=12,
                   restarts=3, twr_per_distance=200)


def _row(name: str, value: float, unit: str, paper: float | None = None, note: str = "") -> dict[str, Any]:
    v = float(value)
    return {"name": name, "value": v if np.isfinite(v) else None, "unit": unit, "paper": paper, "note": note}


def _sigma_s(sc: Scenario, rx_dbm: FloatArray) -> float:
    """RMS per-timestamp jitter (s) the scenario's timestamp_noise gives at these powers."""
    tn = sc.effects["timestamp_noise"]
    if not tn.enabled:
        return 0.0
    v = tn.values()
    sig = models.timestamp_sigma_s(rx_dbm, v["floor_ps"], v["snr_ps"], v["ref_dbm"])
    return float(np.sqrt(np.mean(sig**2)))


def _truth_per_step(rec: dict[str, Any], truth: dict[str, Any],
                    cal: PowerCalibration) -> tuple[FloatArray, FloatArray]:
    """(true real power of P2, true E(P2) - E(P1) in s) per step of a calibration."""
    step = np.asarray(rec["step"])
    real = np.array([np.mean(truth["rx_dbm2"][step == s.step]) for s in cal.steps])
    err = np.array([np.mean((truth["bias_s2"] - truth["bias_s1"])[step == s.step]) for s in cal.steps])
    return real, err


def curve_rms_m(cal: PowerCalibration, true_err_s: FloatArray) -> float:
    """RMS (m) of the estimated per-step error minus truth, after removing the mean (the constant)."""
    d = np.array([s.error_s for s in cal.steps]) - true_err_s
    return float(np.sqrt(np.mean((d - d.mean()) ** 2)) * C)


def real_rms_db(cal: PowerCalibration, true_real: FloatArray) -> float:
    """RMS (dB) of the estimated real power per step minus the true mean RX power."""
    return float(np.sqrt(np.mean((np.array([s.real_dbm for s in cal.steps]) - true_real) ** 2)))


def _calibrate(rec: dict[str, Any], method: str = "auto") -> PowerCalibration:
    m2 = analysis.measured_level(rec, "2")
    m1 = analysis.measured_level(rec, "1")
    from uwbcal.corrections.power import calibrate_power

    assert m2 is not None
    return calibrate_power(rec["tx1"], rec["tx2"], rec["tx3"], rec["rx1"], rec["rx2"], rec["rx3"],
                           rec["step"], rec["gain13"], rec["gain2"], m2, m1, method=method,
                           rx_station=int(rec["rx_station"][0]))


def with_effects_of(base: Scenario, other: Scenario) -> Scenario:
    """``base`` (its geometry and stations) with the effects of ``other`` (switches and parameters)
    and, for station ids both have, ``other``'s RX and TX timestamp-noise scales: how a scenario fitted by
    `uwbcal gap --write-scenario` enters the paper's experiments."""
    sc = base.with_effects(enabled={n: e.enabled for n, e in other.effects.items()},
                           params={n: e.values() for n, e in other.effects.items()})
    for sid in set(base.station_ids) & set(other.station_ids):
        st = other.station(sid)
        sc = sc.with_station(sid, noise_scale=st.noise_scale, tx_noise_scale=st.tx_noise_scale)
    return sc


def run_paper(out: Path, quick: bool = False, seed: int = 1, plots: bool = True,
              log: Callable[[str], None] | None = None,
              effects_from: Scenario | None = None) -> dict[str, Any]:
    """Run every experiment; write figures into ``out`` (if ``plots``); return the result dict
    {"headline": [...], "bars": {...}, "figures": [...], "details": {...}, "seconds": ...}.

    ``effects_from``: a scenario whose effects replace the paper scenarios' (see
    :func:`with_effects_of`); the stations and distances stay the paper's."""
    from uwbcal import plots as pl

    say = log or (lambda _m: None)
    sizes = PaperSizes.quick() if quick else PaperSizes()
    t_start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    figs: list[str] = []
    details: dict[str, Any] = {}
    bars: dict[str, Any] = {}
    ant = load_scenario("paper_antenna")
    cab = load_scenario("paper_cable")
    if effects_from is not None:
        ant, cab = with_effects_of(ant, effects_from), with_effects_of(cab, effects_from)

    # -- 1. drift ------------------------------------------------------------------------------
    say("drift")
    w = World(ant, seed)
    rec, truth = vectorsim.run_triplets(w, vectorsim.drift_schedule(w, sizes.drift_triplets, spacing_s=2e-3))
    d = analysis.analyze_drift_records(rec)[0]
    sig = _sigma_s(ant, np.concatenate([truth["rx_dbm1"], truth["rx_dbm2"]]))
    floor = noise_floor_m(sig, d["corrected"]["n"])
    details["drift"] = d
    rows += [
        _row("drift: C12 mean before correction", d["uncorrected"]["mean_m"], "m", None,
             f"{d['drift_ppm_mean']:+.2f} ppm at 2 ms; the paper shows about 1 m for its clocks"),
        _row("drift: mean residual C'12 after eq. 1", d["corrected"]["mean_m"], "m", -1.915e-5,
             f"{d['corrected']['n']} triplets in warm-up; noise floor (SEM) {floor:.1e} m"),
        _row("drift: std of C'12 after eq. 1", d["corrected"]["std_m"], "m", None,
             f"theory sqrt(1.5) sigma c = {noise_floor_m(sig, 1):.2e} m"),
        _row("drift: mean with carrier-integrator correction", d["carrier_integrator"]["mean_m"], "m", None,
             "integrator error depends on RX power"),
    ]
    bars["drift_abs_mean_le_1e-4_m"] = abs(d["corrected"]["mean_m"]) <= 1e-4
    if plots:
        series = analysis.drift_residual_series(rec)
        win = max(1, sizes.drift_triplets // 40)
        figs.append(str(pl.plot_drift(series, out / "fig_drift.png", noise_floor_m(sig, win), win,
                                      "Clock drift correction (eq. 1), 2 ms, warm-up")))

    # -- 2. carrier integrator jump ---------------------------------------------------------
    say("carrier integrator")
    w = World(ant, seed + 1)
    n = sizes.jump_triplets
    sch = vectorsim.drift_schedule(w, 2 * n, spacing_s=2e-3, period_s=0.05)
    low = gain_ladder(vectorsim.DEFAULT_GAIN, 10.0, 2)[1]
    sch.gain13[n:] = low
    sch.gain2[n:] = low
    rec, truth = vectorsim.run_triplets(w, sch)
    series = analysis.drift_residual_series(rec)
    from uwbcal.corrections.drift import drift_ratio, triplet_diffs

    dd = triplet_diffs(rec["tx1"], rec["tx2"], rec["tx3"], rec["rx1"], rec["rx2"], rec["rx3"])
    eq1_ppm = drift_ratio(dd) * 1e6
    ci_ppm = -series["car_int_ppm"]  # RX relative to TX, like eq. 1
    k = min(200, n)

    def jump(x: FloatArray) -> float:
        return float(np.mean(x[n:n + k]) - np.mean(x[n - k:n]))

    true_ppm = np.asarray(truth["offset_ppm"])  # RX minus TX, like eq. 1 and -car_int_to_ppm
    dp = jump(series["measured1_dbm"])
    sem_eq1 = float(np.std(eq1_ppm[:n] - true_ppm[:n], ddof=1) * np.sqrt(2.0 / k))
    rows += [
        _row("carrier integrator: jump when only TX power changes", jump(ci_ppm), "ppm", None,
             f"measured level changes {dp:+.1f} dB (real about -10 dB); means of {k} before/after; "
             f"true clock offset changes {jump(true_ppm):+.3f} ppm (warm-up)"),
        _row("carrier integrator: error jump (minus truth)", jump(ci_ppm - true_ppm), "ppm", None,
             "integrator error depends on RX power"),
        _row("eq. 1 drift estimate: error jump (minus truth) at the same moment", jump(eq1_ppm - true_ppm),
             "ppm", None, f"noise floor (SEM of difference) {sem_eq1:.1e} ppm"),
    ]
    if plots:
        series["drift_ppm"] = eq1_ppm
        series["car_int_ppm"] = ci_ppm
        figs.append(str(pl.plot_carint_jump(series, out / "fig_carint_jump.png", sem_eq1, max(1, n // 40))))

    # -- 3./4./5. power by cable and by antenna, measured vs real --------------------------------
    cals: dict[str, PowerCalibration] = {}
    truths: dict[str, tuple[FloatArray, FloatArray]] = {}
    for label, sc, step_db, steps in (("cable 3 dB", cab, 3.0, sizes.cable_steps),
                                      ("antenna 0.5 dB", ant, 0.5, sizes.antenna_steps)):
        say(f"power {label}")
        w = World(sc, seed + 2)
        sch = vectorsim.power_schedule(w, steps, sizes.per_step, step_db=step_db)
        rec, truth = vectorsim.run_triplets(w, sch)
        cal = _calibrate(rec)
        nominal = _calibrate(rec, "nominal")
        t_real, t_err = _truth_per_step(rec, truth, cal)
        cals[label], truths[label] = cal, (t_real, t_err)
        c_rms = curve_rms_m(cal, t_err)
        r_rms = real_rms_db(cal, t_real)
        span = (max(s.error_s for s in cal.steps) - min(s.error_s for s in cal.steps)) * C
        sem = float(np.median([s.error_sem_s for s in cal.steps]) * C)
        key = label.split()[0]
        details[f"power_{key}"] = cal.to_dict()
        rows += [
            _row(f"power {label}: curve RMS vs truth (constant removed)", c_rms, "m", None,
                 f"bar 0.005 m; per-step noise floor (SEM) {sem:.1e} m"),
            _row(f"power {label}: curve span over the sweep", span, "m", None,
                 f"real {min(t_real):.1f}..{max(t_real):.1f} dBm"),
            _row(f"measured vs real ({label}): RMS error, method {cal.method}", r_rms, "dB", None,
                 "bar 0.5 dB"),
            _row(f"measured vs real ({label}): RMS error, paper's line through nominal steps",
                 real_rms_db(nominal, t_real), "dB", None,
                 f"fitted slope {nominal.slope:.3f} on {nominal.n_fit} steps below "
                 f"{nominal.threshold_dbm} dBm"),
        ]
        bars[f"power_{key}_curve_rms_le_5mm"] = c_rms <= 0.005
        bars[f"power_{key}_real_rms_le_0.5dB"] = r_rms <= 0.5
    if plots:
        for label, cal in cals.items():
            t_real, t_err = truths[label]
            meas = np.array([s.measured_dbm for s in cal.steps])
            tr_err = t_err - np.mean(t_err - np.array([s.error_s for s in cal.steps]))
            figs.append(str(pl.plot_power([(label, cal)], out / f"fig_power_{label.split()[0]}.png",
                                          f"Power self-calibration, {label}", truth=[(meas, tr_err * C)])))
        figs.append(str(pl.plot_measured_vs_real(
            list(cals.items()), out / "fig_measured_vs_real.png",
            truth=[(truths[lb][0], np.array([s.measured_dbm for s in c.steps])) for lb, c in cals.items()])))

    # -- 6. spacing 150 us against 2 ms -------------------------------------------------------
    say("spacing")
    w = World(ant, seed + 2)
    rec, truth = vectorsim.run_triplets(w, vectorsim.power_schedule(w, sizes.antenna_steps, sizes.per_step,
                                                                  step_db=0.5, spacing_s=150e-6))
    cal150 = _calibrate(rec)
    cal2 = cals["antenna 0.5 dB"]
    e150 = np.array([s.error_s for s in cal150.steps])
    e2 = np.array([s.error_s for s in cal2.steps])
    diff = (e150 - e2) * C
    rows += [
        _row("spacing: C'12 at equal gains (step 0), 150 us", cal150.steps[0].error_s * C, "m", None,
             f"2 ms: {cal2.steps[0].error_s * C:.1e} m; SEM {cal150.steps[0].error_sem_s * C:.1e} m"),
        _row("spacing: mean curve difference 150 us - 2 ms", float(np.mean(diff)), "m", None,
             "messages 150 us apart disturb each other (P1/P3 offset)"),
    ]
    if plots:
        figs.append(str(pl.plot_power([("2 ms", cal2), ("150 us", cal150)], out / "fig_spacing.png",
                                      "Spacing: 150 us against 2 ms")))

    # -- 7. repeatability and two stations -------------------------------------------------------
    say("repeatability")
    rep: list[PowerCalibration] = []
    for r in range(sizes.restarts):
        w = World(ant, seed + 100 + r)
        sched = vectorsim.power_schedule(w, sizes.antenna_steps, sizes.per_step, step_db=0.5, tx=1, rx=2)
        rec, truth = vectorsim.run_triplets(w, sched)
        rep.append(_calibrate(rec))
    grid = np.linspace(max(max(c.curve.real_dbm[0] for c in rep), cal2.curve.real_dbm[0]),
                       min(min(c.curve.real_dbm[-1] for c in rep), cal2.curve.real_dbm[-1]), 50)
    curves6 = np.array([c.curve.error_at_real(grid) for c in rep])
    curves6 -= curves6.mean(axis=1, keepdims=True)
    spread = float(np.sqrt(np.mean((curves6 - curves6.mean(axis=0)) ** 2)) * C)
    other = cal2.curve.error_at_real(grid)
    other = other - other.mean()
    between = float(np.sqrt(np.mean((curves6.mean(axis=0) - other) ** 2)) * C)
    rows += [
        _row(f"repeatability: RMS spread of {sizes.restarts} restarts (station 2)", spread, "m", None,
             "paper: curves deterministic over six restarts"),
        _row("two stations: RMS difference of the curves (station 2 vs 1)", between, "m", None,
             "paper: shapes differ per station"),
    ]
    if plots:
        labelled = [(f"st.2 run {i + 1}", c) for i, c in enumerate(rep)] + [("st.1", cal2)]
        figs.append(str(pl.plot_power(labelled, out / "fig_repeatability.png",
                                      "Repeatability and two stations")))

    # -- 8. TWR --------------------------------------------------------------------------------
    say("twr")
    curves = {2: rep[0].curve, 1: cal2.curve}
    w = World(ant, seed + 3)
    rec, truth = vectorsim.run_ranges(w, vectorsim.twr_schedule(w, per_distance=sizes.twr_per_distance,
                                                              gain=TWR_GAIN))
    tw = analysis.analyze_twr_records(rec, curves)
    details["twr"] = tw
    sig_twr = _sigma_s(ant, np.concatenate([truth["rx_dbm_t1"], truth["rx_dbm_r2"]]))
    # T_TOA carries RX noise of t2r (x1), t1t (x(1 - r)) and t3t (x r), r = dT12 / dT13 = 0.5 here,
    # halved: 0.5 sqrt(1.5) sigma per exchange (quantisation added in quadrature)
    twr_floor = float(0.5 * np.sqrt(1.5) * np.hypot(sig_twr, dw1000.TIME_UNIT_S / np.sqrt(12)) * C)
    for name, m in tw["methods"].items():
        rows.append(_row(f"TWR {name}: error std, 11 distances", m["std_all_m"], "m",
                         0.015 if name == "paper" else None,
                         f"{m['description']}; RMS of per-distance means {m['rms_of_means_m']:.4f} m; "
                         f"mean std within a distance {m['mean_within_std_m']:.4f} m "
                         f"(timestamp-noise floor {twr_floor:.4f} m)"))
    tw_avg = analysis.analyze_twr_records(rec, curves, level_window=16)["methods"]["paper"]
    rows.append(_row("TWR paper, RX level averaged over 16 exchanges: error std", tw_avg["std_all_m"], "m",
                     0.015,
                     f"mean std within a distance {tw_avg['mean_within_std_m']:.4f} m: the level "
                     "estimate's noise no longer enters E1, E2"))
    w = World(ant, seed + 4)
    rec_full, _ = vectorsim.run_ranges(w, vectorsim.twr_schedule(w, per_distance=sizes.twr_per_distance))
    tw_full = analysis.analyze_twr_records(rec_full, curves)["methods"]["paper"]
    rows.append(_row("TWR paper at full TX gain: error std, 11 distances", tw_full["std_all_m"], "m", 0.015,
                     "short distances receive more power than the 1.5 m calibration swept: the curve is "
                     f"clamped there; RMS of per-distance means {tw_full['rms_of_means_m']:.4f} m"))
    mth = tw["methods"]
    bars["twr_std_le_0.015_m"] = mth["paper"]["std_all_m"] <= 0.015
    bars["twr_worse_without_power"] = mth["paper_no_power"]["std_all_m"] > 1.5 * mth["paper"]["std_all_m"]
    bars["twr_worse_without_drift"] = mth["paper_no_drift"]["std_all_m"] > 1.5 * mth["paper"]["std_all_m"]
    if plots:
        figs.append(str(pl.plot_twr(tw, out / "fig_twr.png", twr_floor)))

    secs = time.perf_counter() - t_start
    return {"headline": rows, "bars": bars, "figures": figs, "details": details, "seconds": secs,
            "quick": quick, "seed": seed}


#: Markers around the generated results table in docs/PAPER.md (`uwbcal paper --doc`).
DOC_BEGIN = "<!-- generated by `uwbcal paper --out DIR --doc docs/PAPER.md` (seed {seed}); do not edit -->"
DOC_END = "<!-- end of the generated table -->"


def update_doc(path: Path, result: dict[str, Any]) -> None:
    """Put the headline table of ``result`` between the markers of the doc at ``path``
    (ValueError when the doc has no markers, or ``result`` is a --quick run)."""
    import re

    if result.get("quick"):
        raise ValueError("the doc holds the full run: run without --quick")
    text = path.read_text(encoding="utf-8")
    pat = re.compile(re.escape(DOC_BEGIN).replace(r"\{seed\}", r"\d+") + r".*?" + re.escape(DOC_END), re.S)
    if not pat.search(text):
        raise ValueError(f"{path}: no generated-table markers ({DOC_END!r})")
    block = DOC_BEGIN.format(seed=result["seed"]) + "\n" + table_markdown(result) + "\n" + DOC_END
    path.write_text(pat.sub(lambda _m: block, text), encoding="utf-8")


def doc_table(path: Path) -> tuple[int, dict[str, float | None]]:
    """The seed and the rows (quantity name -> simulated value) of the doc's generated table."""
    import re

    text = path.read_text(encoding="utf-8")
    m = re.search(re.escape(DOC_BEGIN).replace(r"\{seed\}", r"(\d+)") + r"\n(.*?)" + re.escape(DOC_END), text,
                  re.S)
    if m is None:
        raise ValueError(f"{path}: no generated table")
    rows: dict[str, float | None] = {}
    for line in m.group(2).splitlines()[2:]:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        rows[cells[0]] = None if cells[1] == "n/a" else float(cells[1])
    return int(m.group(1)), rows


def table_markdown(result: dict[str, Any]) -> str:
    """The headline rows as a Markdown table."""
    lines = ["| quantity | simulated | unit | paper | note |", "|---|---|---|---|---|"]
    for r in result["headline"]:
        v = "n/a" if r["value"] is None else f"{r['value']:.4g}"
        p = "" if r["paper"] is None else f"{r['paper']:.4g}"
        lines.append(f"| {r['name']} | {v} | {r['unit']} | {p} | {r['note']} |")
    return "\n".join(lines)
