"""Report of a gap diagnosis: text, JSON (engine.Diagnosis.to_json) and plots (PNG).

Plots: ``gap_localisation.png`` (floor z-scores of the cells that differ, per observable and
regime), ``gap_regimes.png`` (per observable, the largest |z| of every regime bin before and
after the named effects), ``gap_residuals.png`` (per observable and statistic, the mean
standardised residual per group before and after the named effects). matplotlib is imported
inside the functions.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from uwbcal.gap import criticism, stats
from uwbcal.gap.engine import Diagnosis


def _fmt(x: Any, pct: bool = False) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{100 * x:.0f}%" if pct else f"{x:.4g}"


def _least_words(d: Diagnosis) -> str:
    """ ", held back by ..." when an aspect other than the held-out feature loss sets the shrink."""
    least = d.shrink.get("least", "features")
    a = d.shrink_aspects
    if least == "time_shape":
        return (
            f" (the held-out feature loss shrinks {_fmt(a.get('features'), True)}, but the time shape "
            f"is not reproduced: {_fmt(a.get('time_shape'), True)} of its failing checks pass)"
        )
    if least == "cells":
        return (
            f" (the held-out feature loss shrinks {_fmt(a.get('features'), True)}, but only "
            f"{_fmt(a.get('cells'), True)} of the differing cells close)"
        )
    return ""


_PLAIN_OBS = {
    "drift_residual_m": "drift-corrected residual (eq. 1)",
    "clock_rate_ppm": "clock rate",
    "rx_level_dbm": "reported RX level",
    "p13_level_db": "P3 - P1 level",
    "car_int_ppm_minus_rate": "carrier-integrator error",
}


def _value(n: dict[str, Any]) -> str:
    """A named effect's fitted value in physical units, with the believed one."""
    u = f" {n['unit']}" if n["unit"] else ""
    return f"{n['fitted']:.3g}{u} (the scenario believed {n['baseline']:.3g}{u})"


_ROW_KEYS = (
    "residual_sd_real_cm",
    "residual_sd_sim_cm",
    "residual_sd_with_named_cm",
    "rate_real_ppm",
    "rate_sim_ppm",
    "rate_with_named_ppm",
)


def per_direction(d: Diagnosis) -> list[dict[str, Any]]:
    """Per direction: real and simulated residual SD (cm) and clock rate (ppm), before and with
    the named effects (the direction cells of the localisation)."""
    after = {c.ident: c for c in d.cells_after}
    rows: dict[str, dict[str, Any]] = {}
    for c in d.cells:
        if c.regime != "direction" and not (
            c.regime == "all" and not any(x.regime == "direction" for x in d.cells)
        ):
            continue
        row = rows.setdefault(c.label, {"direction": c.label, "n": c.n_real})
        a = after.get(c.ident)
        if c.observable == "drift_residual_m":
            row.update(
                residual_sd_real_cm=100 * c.real_sd,
                residual_sd_sim_cm=100 * c.sim_sd,
                residual_sd_with_named_cm=100 * a.sim_sd if a else float("nan"),
                residual_z_scale=c.z[2] if c.z else float("nan"),
            )
        elif c.observable == "clock_rate_ppm":
            row.update(
                rate_real_ppm=c.real_mean,
                rate_sim_ppm=c.sim_mean,
                rate_with_named_ppm=a.sim_mean if a else float("nan"),
            )
    per = d.station_noise.get("directions", {}) if d.station_noise else {}
    for label, row in rows.items():
        if label in per:
            row["jitter_rms_ps"] = per[label]["rms_ps"]
    return list(rows.values())


def headline(d: Diagnosis, believed: str = "the believed scenario") -> str:
    """One paragraph an engineer can act on: where, which effect and its value, how much of the
    gap it removes, how sure; or why nothing is named."""
    from uwbcal.gap.fitted import plain_name

    if d.verdict == "no significant gap":
        return (
            f"No significant gap: the recording agrees with {believed} within the simulation's own "
            f"seed-to-seed noise in all {len(d.cells)} cells (per direction, time block and regime)."
        )
    where: dict[str, list[str]] = {}
    for c in d.significant[:40]:
        where.setdefault(_PLAIN_OBS.get(c.observable, c.observable), []).append(c.label.split(",")[0])
    wtxt = "; ".join(f"{o} ({', '.join(sorted(set(v))[:3])})" for o, v in list(where.items())[:3])
    parts = [f"The recording differs from {believed} in {len(d.significant)} cells, mostly the {wtxt}."]
    if d.named:
        eff = "; ".join(f"{plain_name(n)} {_value(n)}" for n in d.named)
        parts.append(f"Best catalogue explanation: {eff}.")
        sh = d.shrink
        parts.append(
            f"With these, {_fmt(sh['estimate'], True)} of the gap goes away "
            f"[{_fmt(sh['ci_low'], True)}, {_fmt(sh['ci_high'], True)}]{_least_words(d)}."
        )
    if d.verdict == "explained":
        parts.append("Verdict: explained (margin over the runner-up and model criticism passed).")
    elif d.verdict == "unstable":
        parts.append(
            "Verdict: none (refused as unstable: the seed ensembles disagree; the effects above are "
            "those most ensembles name)."
        )
    else:
        why = (
            d.summary.split("but ", 1)[1] if "but " in d.summary else "no candidate improves held-out groups"
        )
        parts.append(f"Verdict: unexplained: {why}.")
    stab = d.settings.get("stability")
    if isinstance(stab, dict):
        parts.append(
            f"Stability over {stab['ensembles']} seed ensembles: {stab['verdict_share']:.0%} agree on the "
            f"verdict, {stab['named_share']:.0%} on the named effects."
        )
    if d.station_noise.get("named"):
        parts.append("Noisier stations (the session's ids): " + ", ".join(d.station_noise["named"]) + ".")
    if d.local_departures:
        ld = d.local_departures[0]
        parts.append(
            f"A time-local departure: {ld['direction']} {ld['start_s']:.0f}..{ld['end_s']:.0f} s "
            f"(spread x{ld['scale_ratio']:.2g})."
        )
    return " ".join(parts)


def text(d: Diagnosis, title: str = "") -> str:
    """A human-readable report (a few dozen lines): the headline paragraph, then the details."""
    lines = [
        f"gap diagnosis{': ' + title if title else ''}",
        headline(d),
        "",
        f"verdict: {d.verdict}",
        d.summary,
        "",
    ]
    pdir = per_direction(d)
    if pdir:
        lines.append("per direction (real | simulated | with the named effects):")
        for r in pdir:
            g = {k: _fmt(r.get(k)) for k in _ROW_KEYS}
            lines.append(
                f"  {r['direction']:6s} n={r['n']:6d}  residual SD {g['residual_sd_real_cm']} | "
                f"{g['residual_sd_sim_cm']} | {g['residual_sd_with_named_cm']} cm  clock rate "
                f"{g['rate_real_ppm']} | {g['rate_sim_ppm']} | {g['rate_with_named_ppm']} ppm"
            )
        lines.append("")
    lines.append(
        f"localisation: {len(d.cells)} cells x {len(stats.STAT_NAMES)} statistics "
        f"({', '.join(stats.STAT_NAMES)}), BH FDR {d.settings.get('alpha')}; "
        f"{len(d.significant)} cells differ"
    )
    for c in d.significant[:12]:
        j = c.to_json()
        worst = int(min(range(len(c.q)), key=lambda i: c.q[i]))
        lines.append(
            f"  {c.observable:24s} {c.regime:11s} {c.label:22s} n={c.n_real:6d}  "
            f"real {j['real_mean']:+.4g} sd {j['real_sd']:.3g} | "
            f"sim {j['sim_mean']:+.4g} sd {j['sim_sd']:.3g} "
            f"{j['unit']}  worst: {stats.STAT_NAMES[worst]} z={c.z[worst]:+.1f} q={c.q[worst]:.1e}"
        )
    if len(d.significant) > 12:
        lines.append(f"  ... {len(d.significant) - 12} more (see --json)")
    if d.selection_steps:
        lines.append("")
        lines.append("attribution (held-out NLL improvement per group, mean and CI; forward selection):")
        for st in d.selection_steps:
            if "candidates" in st:  # clock shapes fitted to the rate (model.clock_shapes)
                lines.append(
                    f"  {st['step']}: {'; '.join(st['candidates'])} -> {' + '.join(st['named']) or 'none'} "
                    f"(passes the checks: {st['passes']})"
                )
                continue
            if "from" in st:  # shape refinement of the effect named first (model.shape_refiner)
                lines.append(
                    f"  {st['step']}: {st['from']} -> {st['to']}"
                    + ("" if "passes" not in st else f" (passes the checks: {st['passes']})")
                )
                continue
            if "instead_of" in st:  # every receiver's own scale named: one global knob tried (engine)
                lines.append(
                    f"  {st['step']}: instead of {' + '.join(st['instead_of'])} -> "
                    f"{' + '.join(st.get('named', [])) or 'none'} (passes the checks: {st.get('passes')}"
                    + (f"; kept: {st['kept']})" if "kept" in st else ")")
                )
                continue
            if "dropped" in st:  # an effect whose re-simulations only added a discrepancy (engine)
                lines.append(f"  {st['step']}: {st['dropped']} ({st['why']})")
                continue
            if "ranking" not in st:  # the free per-step terms (gap/free.py)
                need = ", ".join(
                    f"{k} {v['heldout_improvement']:.3g} [{v['ci'][0]:.3g}, {v['ci'][1]:.3g}]"
                    for k, v in st.get("needed", {}).items()
                )
                lines.append(
                    f"  {st['step']}: needed {need or 'none'} -> {st.get('named')}"
                    + ("" if "passes" not in st else f" (passes the checks: {st['passes']})")
                )
                continue
            top = ", ".join(
                f"{r['effect']} {r['heldout_improvement']:.3g} [{r['ci'][0]:.3g}, {r['ci'][1]:.3g}]"
                for r in st["ranking"][:4]
            )
            lines.append(f"  step {st['step']}: {top}")
            chance = [c for c in st.get("chance", []) if not c["beyond_chance"]]
            if chance:  # picks within what believed re-simulations give (attribute._beyond_chance)
                lines.append(
                    "    not named, no more than on a believed re-simulation: "
                    + ", ".join(
                        f"{c['effect']} {c['heldout_improvement']:.3g} "
                        f"(up to {c['on_believed_resimulations']:.3g} on {c['n_resimulations']})"
                        for c in {c["effect"]: c for c in chance}.values()
                    )
                )
    for n in d.named:
        lines.append(
            f"  named: {n['effect']}: {n['knob']} = {n['fitted']:.5g} {n['unit']} "
            f"(believed {n['baseline']:.5g}){' AT GRID EDGE' if n['at_grid_edge'] else ''}"
        )
    if d.lasso:
        lines.append(
            "  lasso cross-check (mean signatures): "
            + ", ".join(f"{r['effect']}@{r['at']:.3g}" for r in d.lasso[:4])
            + f"; agrees: {d.lasso_agrees}"
        )
    if d.named:
        s, b = d.shrink, d.blackbox_shrink
        lines.append("")
        a = d.shrink_aspects
        fci = a.get("features_ci", [float("nan")] * 2)
        lines.append(
            f"shrink of the gap (the least aspect, {s.get('least', 'features')}): "
            f"{_fmt(s['estimate'], True)} "
            f"[{_fmt(s['ci_low'], True)}, {_fmt(s['ci_high'], True)}]"
        )
        lines.append(
            f"  held-out feature loss (re-simulated, 2-fold): {_fmt(a.get('features'), True)} "
            f"[{_fmt(fci[0], True)}, {_fmt(fci[1], True)}]; differing cells closed: "
            f"{_fmt(a.get('cells'), True)}; failing time-shape checks passed: "
            f"{_fmt(a.get('time_shape'), True)}"
        )
        lines.append(
            f"  black-box residual model (features): "
            f"{_fmt(b['estimate'], True)} [{_fmt(b['ci_low'], True)}, {_fmt(b['ci_high'], True)}]; "
            f"named / black-box: {_fmt(d.fraction_of_removable, True)}"
        )
        if d.remaining:
            lines.append(f"cells still differing with the named effects: {len(d.remaining)}")
            for c in d.remaining[:6]:
                worst = int(min(range(len(c.q)), key=lambda i: c.q[i]))
                lines.append(
                    f"  {c.observable:24s} {c.regime:11s} {c.label:22s} "
                    f"{stats.STAT_NAMES[worst]} z={c.z[worst]:+.1f} q={c.q[worst]:.1e}"
                )
    if d.criticism:
        lines.append("")
        lines.append(
            "model criticism of the named effects (block-mean increments, block spreads;"
            " z against re-simulations):"
        )
        for c in d.criticism:
            lines.append(
                f"  {c.observable:18s} {c.direction:6s} "
                + "  ".join(f"{k} z={z:+.1f}" for k, z in zip(criticism.CHECKS, c.z, strict=True))
            )
        if d.criticism_failed:
            lines.append("  FAILED: " + "; ".join(d.criticism_failed))
    if d.ambiguous:
        lines.append("ambiguous (runner-up within the margin): " + "; ".join(d.ambiguous))
    sn = d.station_noise
    if sn:
        lines.append("")
        if sn.get("separable"):
            lines.append(
                "per-station timestamp noise, the session's station ids (excess over the quietest station, "
                "RMS ps, 95% CI; over the others' mean, z; named past z "
                f"{sn.get('z_named', float('nan')):.2f}, Bonferroni):"
            )
            for r in sn["excess_over_quietest"]:
                lines.append(
                    f"  station {r['station']} {r['side'].upper()}: {r['excess_rms_ps']:.0f} "
                    f"[{r['ci_ps'][0]:.0f}, {r['ci_ps'][1]:.0f}]; "
                    f"{r.get('excess_over_others_rms_ps', float('nan')):+.0f} "
                    f"(z {r.get('z', float('nan')):+.1f})"
                    f"{'  NAMED' if r['named'] else ''}"
                )
        else:
            lines.append(f"per-station noise: {sn.get('reason', 'n/a')}")
    for ld in d.local_departures:
        lines.append(
            f"time-local departure: {ld['direction']} {ld['start_s']:.1f}..{ld['end_s']:.1f} s, "
            f"residual spread x{ld['scale_ratio']:.2f} (z {ld['z']:+.1f}, threshold {ld['threshold_z']:.1f})"
        )
    return "\n".join(lines)


def markdown(d: Diagnosis, title: str, believed: str, plot_files: list[Path]) -> str:
    """The report as markdown: the headline paragraph, per-direction figures, named effects in
    plain names, then the details and the plots inline."""
    from uwbcal.gap.fitted import plain_name

    out = [f"# Gap diagnosis: {title}", "", headline(d, believed), ""]
    pdir = per_direction(d)
    if pdir:
        out += [
            "## Per direction",
            "",
            "| direction | records | residual SD real / sim / with named (cm) "
            "| clock rate real / sim / with named (ppm) | jitter RMS (ps) |",
            "|---|---|---|---|---|",
        ]
        for r in pdir:
            out.append(
                f"| {r['direction']} | {r['n']} | {_fmt(r.get('residual_sd_real_cm'))} / "
                f"{_fmt(r.get('residual_sd_sim_cm'))} / {_fmt(r.get('residual_sd_with_named_cm'))} | "
                f"{_fmt(r.get('rate_real_ppm'))} / {_fmt(r.get('rate_sim_ppm'))} / "
                f"{_fmt(r.get('rate_with_named_ppm'))} | {_fmt(r.get('jitter_rms_ps'))} |"
            )
        out.append("")
    if d.named:
        out += ["## Named effects", "", "| effect | fitted | believed | knob |", "|---|---|---|---|"]
        for n in d.named:
            u = n["unit"]
            out.append(
                f"| {plain_name(n)} | {n['fitted']:.4g} {u} | {n['baseline']:.4g} {u} | `{n['knob']}` |"
            )
        out.append("")
        for n in d.named:  # free terms (gap/free.py): the value of every step, or of every level
            if n.get("per_step"):
                out += [f"**{plain_name(n)}**, per step ({n['unit'] or 'log factor'}): "]
                out += ["| receiver, step | value |", "|---|---|"]
                out += [f"| {k} | {v:+.4g} |" for k, v in n["per_step"].items()]
                out.append("")
            if n.get("per_level"):
                out += [f"**{plain_name(n)}**, the reported level's change at each level (dB): "]
                out += ["| receiver, level | change |", "|---|---|"]
                out += [f"| {k} | {v:+.3g} |" for k, v in n["per_level"].items()]
                out.append("")
    out += ["## Details", "", "```", text(d, title), "```", ""]
    for pth in plot_files:
        out += [f"![{pth.stem}]({pth.name})", ""]
    return "\n".join(out)


def plots(d: Diagnosis, out_dir: Path) -> list[Path]:
    """Write the PNG plots; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    cells = d.significant[:30] or sorted(d.cells, key=lambda c: min(c.p))[:15]
    fig, ax = plt.subplots(figsize=(10, max(3.0, 0.28 * len(cells) + 1)))
    labels = [f"{c.observable} | {c.regime} {c.label}" for c in cells]
    for i, name in enumerate(stats.STAT_NAMES):
        ax.scatter([c.z[i] if c.z else 0.0 for c in cells], range(len(cells)), s=14, label=name)
    ax.set_yticks(range(len(cells)))
    ax.set_yticklabels(labels, fontsize=7)
    ax.axvline(0, color="k", lw=0.6)
    ax.set_xscale("symlog", linthresh=3)
    ax.set_xlabel("z against the sim-vs-sim floor (real vs re-simulated schedule)")
    ax.set_title(
        f"where the gap is: {d.verdict} ({len(d.significant)} cells at FDR {d.settings.get('alpha')})"
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    p = out_dir / "gap_localisation.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)

    p_reg = _plot_regimes(d, out_dir)
    if p_reg is not None:
        paths.append(p_reg)
    keys = [k for k in d.residual_before if k != "groups"]
    if keys:
        ncol = 4
        nrow = math.ceil(len(keys) / ncol)
        fig, axes = plt.subplots(nrow, ncol, figsize=(3.2 * ncol, 2.4 * nrow), squeeze=False)
        for ax, k in zip(axes.ravel(), keys, strict=False):
            ax.plot(d.residual_before[k]["mean_z"], "o-", ms=3, label="before")
            if k in d.residual_after:
                ax.plot(d.residual_after[k]["mean_z"], "s-", ms=3, label="with named effects")
            ax.axhline(0, color="k", lw=0.5)
            ax.set_title(k, fontsize=8)
            ax.set_xlabel(d.group_regime + " group", fontsize=7)
            ax.set_ylabel("mean z", fontsize=7)
            ax.tick_params(labelsize=6)
        for ax in axes.ravel()[len(keys) :]:
            ax.axis("off")
        axes[0, 0].legend(fontsize=6)
        fig.suptitle("standardised residual (real - sim) / floor per group, before and after", fontsize=9)
        fig.tight_layout()
        p = out_dir / "gap_residuals.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths


def _plot_regimes(d: Diagnosis, out_dir: Path) -> Path | None:
    """Largest |z| per regime bin and observable, before and with the named effects."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    obs = sorted({c.observable for c in d.cells})
    if not obs:
        return None
    after = {c.ident: c for c in d.cells_after}
    fig, axes = plt.subplots(len(obs), 1, figsize=(11, 2.6 * len(obs)), squeeze=False)
    for ax, name in zip(axes[:, 0], obs, strict=True):
        cs = [c for c in d.cells if c.observable == name]
        labels = [f"{c.regime}: {c.label}" for c in cs]
        zb = [max(abs(z) for z in c.z) if c.z else 0.0 for c in cs]
        x = range(len(cs))
        ax.bar([i - 0.2 for i in x], zb, width=0.4, label="before")
        if after:
            za = [
                max(abs(z) for z in after[k].z) if (k := c.ident) in after and after[k].z else 0.0 for c in cs
            ]
            ax.bar([i + 0.2 for i in x], za, width=0.4, label="with named effects")
        ax.set_yscale("symlog", linthresh=3)
        ax.set_xticks(list(x))
        ax.set_xticklabels(labels, rotation=60, ha="right", fontsize=6)
        ax.set_ylabel("max |z| vs floor", fontsize=7)
        ax.set_title(name, fontsize=8)
        ax.legend(fontsize=6)
    fig.suptitle("gap per regime: real against re-simulated schedule", fontsize=9)
    fig.tight_layout()
    p = out_dir / "gap_regimes.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p
