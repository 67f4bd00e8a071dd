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

from uwbcal.gap import stats
from uwbcal.gap.engine import Diagnosis


def _fmt(x: Any, pct: bool = False) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{100 * x:.0f}%" if pct else f"{x:.4g}"


def text(d: Diagnosis, title: str = "") -> str:
    """A human-readable report (a few dozen lines)."""
    lines = [f"gap diagnosis{': ' + title if title else ''}", f"verdict: {d.verdict}", d.summary, ""]
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
            top = ", ".join(
                f"{r['effect']} {r['heldout_improvement']:.3g} [{r['ci'][0]:.3g}, {r['ci'][1]:.3g}]"
                for r in st["ranking"][:4]
            )
            lines.append(f"  step {st['step']}: {top}")
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
        lines.append(
            f"held-out shrink (re-simulated, 2-fold): {_fmt(s['estimate'], True)} "
            f"[{_fmt(s['ci_low'], True)}, {_fmt(s['ci_high'], True)}]; black-box residual model: "
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
    return "\n".join(lines)


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
