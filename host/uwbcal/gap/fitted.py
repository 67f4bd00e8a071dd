"""Closing the loop: the believed scenario with the named effects at their fitted values.

`uwbcal gap SESSION --write-scenario fitted.toml` writes it; `uwbcal paper --scenario` and
`uwbcal demo --scenario` (``make demo DEMO_SCENARIO=...``) run on it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from uwbcal.gap import free, model
from uwbcal.physics.scenario import Scenario, parse_scenario


def fitted_scenario(believed: Scenario, named: Sequence[Mapping[str, Any]], name: str) -> Scenario:
    """``believed`` with every named effect's knob set to its fitted value (effects switched on)."""
    # free per-step terms (gap/free.py) are the discrepancy's own shape, not a scenario parameter
    named = [n for n in named if not free.is_free(str(n["knob"]))]
    variant = tuple(
        kv
        for n in named
        for kv in (*((str(k), float(v)) for k, v in n.get("shape", ())), (str(n["knob"]), float(n["fitted"])))
    )
    sc = model.apply_variant(believed, variant)
    desc = "; ".join(f"{plain_name(n)} {n['fitted']:.4g} {n['unit']}".rstrip() for n in named)
    import dataclasses

    return dataclasses.replace(
        sc,
        name=name,
        description=f"{believed.name} with the gap diagnosis' fitted effects: {desc}"
        if named
        else believed.name,
    )


#: Plain names of the knobs' fields and parameters (the report and the fitted scenario's header).
PLAIN: dict[str, str] = {
    "ppm": "clock offset",
    "warmup_ppm": "warm-up amplitude",
    "warmup_tau_s": "warm-up time constant",
    "warmup2_ppm": "second warm-up stage amplitude",
    "warmup2_tau_s": "second warm-up stage time constant",
    "noise_scale": "receiver timestamp-noise scale",
    "tx_noise_scale": "transmitter timestamp-noise scale",
    "rx_delay_error_ps": "RX antenna-delay error",
    "floor_ps": "timestamp noise floor",
    "sigma_ppm_per_sqrt_s": "clock wander (random-walk rate)",
    "ramp_c_per_s": "temperature ramp",
    "exponent": "path-loss exponent",
    "coarse_step_db": "TX coarse gain step",
    "amplitude_m": "power-bias curve amplitude",
    "knee_dbm": "RX power estimate knee",
    "slope_ppm_per_db": "carrier-integrator power slope",
    "amplitude_ps": "interference amplitude",
    "probability": "late-first-path probability",
    "mean_bias_m": "mean late-path excess (m)",
    "excess_shape": "late-path excess gamma shape",
    "centre_dbm": "power-bias curve centre (dBm)",
    "width_db": "power-bias curve width (dB)",
    "high_slope": "RX level estimate slope above the knee",
}


def plain_name(n: Mapping[str, Any]) -> str:
    """A named effect in plain words, e.g. 'timestamp noise floor', 'station 1 clock offset'."""
    kind, a, *rest = str(n["knob"]).split(":")
    if kind + ":" == free.PREFIX:
        rms = "" if str(n["knob"]) == free.MAP_KNOB else " (RMS)"
        return f"{n['effect'].replace('_', ' ')}: {free.words(a)}{rms}"
    if kind == "switch":
        return f"{a.replace('_', ' ')} (switched {'on' if float(n['fitted']) >= 0.5 else 'off'})"
    field = rest[0] if rest else a
    words = PLAIN.get(field, f"{a.replace('_', ' ')} {field.replace('_', ' ')}")
    for k, v in n.get("shape", ()):  # another functional form of the effect than the believed one
        sfield = str(k).split(":")[-1]
        words += f" ({PLAIN.get(sfield, sfield.replace('_', ' '))} {float(v):.4g})"
    return f"station {a} {words}" if kind == "station" else words


def scenario_toml(sc: Scenario, header: Sequence[str]) -> str:
    """The scenario's TOML with a comment header; checked to parse back to the same scenario."""
    body = sc.to_toml()
    again = parse_scenario(body, name=sc.name)
    if again.to_toml() != body:  # pragma: no cover - a serialiser defect, not bad input
        raise ValueError("the fitted scenario does not read back to itself")
    return "".join(f"# {h}\n" for h in header) + body
