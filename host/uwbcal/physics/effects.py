"""The effects catalogue: every named, switchable, parameterised effect of the world model.

Each effect is a frozen dataclass: its class docstring states what it models and its source,
its fields are the parameters (unit and meaning in the field metadata, default in the field),
``enabled`` is the switch. :data:`EFFECTS` maps the effect name to its class. A scenario holds
one instance per effect (:attr:`uwbcal.physics.scenario.Scenario.effects`); switching an effect
off makes the world ideal in that respect (see each docstring for what "off" means).

Per-station hardware values (clock offset, warm-up amplitude, antenna delays, bias-curve scale
and shift, gain non-ideality, ...) live on :class:`uwbcal.physics.scenario.Station`; an effect
switched off neutralises the station values it governs.

Sources named below:
- [paper] Sidorenko et al., "Decawave UWB clock drift correction and power self-calibration"
  (../shared/seed/000_abee54d7ca2cd1c1.txt).
- [UM] Decawave DW1000 User Manual (system time, delayed TX, TX_POWER, RX level 4.7.2,
  carrier integrator), as quoted in ../shared/reference/dw1000-evk1000.md.
- [APS011] Decawave application note APS011 (range bias against RX level; estimated against
  actual RX level).
- [APS014] Decawave application note APS014 (antenna delay calibration; 2.15 mm/degC).
- [Friis] H. T. Friis, "A note on a simple transmission formula", Proc. IRE 34 (1946).
"""

from __future__ import annotations

import dataclasses
import inspect
from dataclasses import dataclass, field
from typing import Any, ClassVar

from uwbcal.errors import ScenarioError


def _p(default: float, unit: str, doc: str) -> Any:
    """A float parameter field with its unit and meaning in the metadata."""
    return field(default=default, metadata={"unit": unit, "doc": doc})


@dataclass(frozen=True)
class Effect:
    """Base of every effect: a name (class attribute) and the on/off switch."""

    name: ClassVar[str] = ""
    enabled: bool = True

    @classmethod
    def parameters(cls) -> dict[str, tuple[float, str, str]]:
        """Parameter name -> (default, unit, meaning), excluding the ``enabled`` switch."""
        out: dict[str, tuple[float, str, str]] = {}
        for f in dataclasses.fields(cls):
            if f.name == "enabled":
                continue
            default: Any = f.default
            out[f.name] = (
                float(default),
                str(f.metadata.get("unit", "")),
                str(f.metadata.get("doc", "")),
            )
        return out

    def values(self) -> dict[str, float]:
        """Current parameter values (without ``enabled``)."""
        return {k: float(getattr(self, k)) for k in self.parameters()}

    def replace(self, enabled: bool | None = None, **params: float) -> Effect:
        """A copy with the switch and/or parameters changed; ScenarioError names a bad key/value."""
        known = self.parameters()
        changes: dict[str, Any] = {}
        for key, value in params.items():
            if key not in known:
                raise ScenarioError(
                    f"effect {self.name!r} has no parameter {key!r} (known: {', '.join(sorted(known))})"
                )
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ScenarioError(
                    f"effect {self.name!r} parameter {key!r}: expected a number "
                    f"in {known[key][1] or 'no unit'}, got {value!r}"
                )
            changes[key] = float(value)
        if enabled is not None:
            if not isinstance(enabled, bool):
                raise ScenarioError(f"effect {self.name!r}: 'enabled' must be true or false, got {enabled!r}")
            changes["enabled"] = enabled
        return dataclasses.replace(self, **changes)


# --- clocks ------------------------------------------------------------------------------


@dataclass(frozen=True)
class ClockOffset(Effect):
    """Constant crystal frequency offset of each station (``Station.ppm``, ppm, + = fast).

    Source: [paper] section "Clock drift correction" (about 5 ppm between two EVK1000 boards);
    [UM] crystal tolerance. Off: every station's ``ppm`` is taken as 0.
    """

    name: ClassVar[str] = "clock_offset"


@dataclass(frozen=True)
class Warmup(Effect):
    """Crystal warm-up after power-on: frequency offset ``ppm + warmup_ppm * exp(-tau / warmup_tau_s)``.

    ``tau`` is the time since the station's power-on (``Station.power_on_s``). The exponential
    approach looks logarithmic on a linear time axis and settles (to 1 %) after about 4.6 time
    constants: the default ``Station.warmup_tau_s`` = 200 s gives the paper's ~15 min. The
    phase is the closed-form integral. Source: [paper] Fig. "Integrator of the PLL" and
    "DW1000 temperature crystal oscillator warm-up" (deterministic over four restarts).
    A second stage ``Station.warmup2_ppm * exp(-tau / warmup2_tau_s)`` (0 unless given) is for
    crystals that settle in two time constants (e.g. tens of seconds, then minutes).
    Off: ``warmup_ppm`` and ``warmup2_ppm`` are taken as 0.
    """

    name: ClassVar[str] = "warmup"


@dataclass(frozen=True)
class ClockWander(Effect):
    """Random walk of each station's clock frequency (random-walk FM).

    The frequency offset is a Wiener process sampled on a grid of ``grid_s`` and linearly
    interpolated; the clock phase is its exact integral (piecewise quadratic), so every query
    order gives the same clock. Source: standard oscillator noise model (IEEE Std 1139);
    magnitude chosen so that it stays below the 2 ms triplet's resolution but shows over
    minutes. Off: no wander.
    """

    name: ClassVar[str] = "clock_wander"
    sigma_ppm_per_sqrt_s: float = _p(2e-4, "ppm/sqrt(s)", "random-walk intensity of the frequency")
    grid_s: float = _p(1.0, "s", "grid of the frequency random walk")


@dataclass(frozen=True)
class Temperature(Effect):
    """Station temperature and its effects on the clock and the hardware delays.

    Temperature: ``ambient_c + self_heating_c * (1 - exp(-tau / heating_tau_s)) + ramp_c_per_s * tau``
    (station fields ``ambient_c``, ``self_heating_c``; global ``heating_tau_s``, ``ramp_c_per_s``).
    Clock: adds ``Station.tempco_ppm_per_c * (T - ref_c)`` ppm (integrated in closed form).
    Delays: the TX and RX hardware delays of each station grow by ``range_drift_m_per_c / c / 2``
    seconds per degC each, so two stations warming together lengthen a TWR range by
    ``range_drift_m_per_c`` per degC. Source: [APS014] / ../shared/reference (about 2.15 mm per
    degC); crystal tempco order of magnitude from AT-cut datasheets. Off: constant ``ambient_c``,
    no clock or delay change.
    """

    name: ClassVar[str] = "temperature"
    ref_c: float = _p(25.0, "degC", "reference temperature of the tempco and the delay drift")
    heating_tau_s: float = _p(600.0, "s", "time constant of self-heating after power-on")
    ramp_c_per_s: float = _p(0.0, "degC/s", "linear ambient ramp")
    range_drift_m_per_c: float = _p(2.15e-3, "m/degC", "TWR range drift when both stations warm")
    sensor_noise_c: float = _p(0.05, "degC", "noise of the recorded temperature reading")


# --- timestamps --------------------------------------------------------------------------


#: Largest ``TimestampNoise.tail_weight``: 1/dof below 1/2, so the jitter's SD stays finite.
TAIL_WEIGHT_MAX = 0.45


@dataclass(frozen=True)
class TimestampNoise(Effect):
    """Jitter of RX timestamps, growing at low SNR (Gaussian unless ``tail_weight``).

    sigma = Station.noise_scale * sqrt(floor_ps**2 + (snr_ps * 10**((ref_dbm - P) / 20))**2), P the
    true RX power (dBm), ``noise_scale`` the receiving station's factor (default 1): the
    leading-edge estimate's jitter scales with 1/amplitude at low SNR; the floor is the chip's
    event-timing precision at high SNR; receivers differ (asil run 2026-01-23-01: eq. 1 residual
    spread 3.83 cm with node 0 receiving, 2.11 cm with node 1; where `uwbcal gap` names it,
    node 0's ``noise_scale`` is 1.55..2.3 on a 44..54 ps floor, docs/GAP.md). Optional TX
    jitter perturbs the true emission time (not the TX stamp), sigma = Station.tx_noise_scale *
    tx_jitter_ps, the transmitting station's factor (default 1). Source: [paper]
    ("15 ps event-timing precision"), [UM] leading-edge first-path detection; defaults chosen
    so a 2 ms triplet's drift-corrected residual is a few mm per triplet, as in the paper's
    averaged figures (fit them to real data with gap/). Off: no jitter.

    ``tail_weight`` w gives the RX jitter a Student-t shape of 1/w degrees of freedom with the
    same SD sigma (0, the default: Gaussian; at most ``TAIL_WEIGHT_MAX`` = 0.45, 2.2 dof): a
    leading-edge detector that now and then triggers off makes rare large errors that a Gaussian
    of the same SD does not (`uwbcal gap` refines w when the jitter is named first but leaves
    cells, docs/GAP.md). The draw is the Gaussian one times sqrt((1/w - 2) / V), V a chi-square
    draw of 1/w dof; w = 0 draws nothing more.
    """

    name: ClassVar[str] = "timestamp_noise"
    floor_ps: float = _p(6.0, "ps", "RX jitter at high SNR")
    snr_ps: float = _p(20.0, "ps", "low-SNR jitter term at ref_dbm")
    ref_dbm: float = _p(-95.0, "dBm", "RX power at which the low-SNR term equals snr_ps")
    tx_jitter_ps: float = _p(2.0, "ps", "jitter of the true emission time around the TX stamp")
    tail_weight: float = _p(0.0, "", "1/dof of the RX jitter's Student-t shape, 0..0.45 (0: Gaussian)")

    def __post_init__(self) -> None:
        if not 0.0 <= self.tail_weight <= TAIL_WEIGHT_MAX:
            raise ScenarioError(
                f"effect 'timestamp_noise' parameter 'tail_weight': expected 0..{TAIL_WEIGHT_MAX} "
                f"(1/dof of a Student-t with a finite SD), got {self.tail_weight!r}"
            )


@dataclass(frozen=True)
class Quantisation(Effect):
    """Timestamps are integer device units of 1/(128*499.2 MHz) = 15.65 ps [UM].

    On: the chip truncates (floor) the exact time to the unit (mean -0.5 unit, common to all
    timestamps, cancels in differences). Off: rounds to the nearest unit (records stay integer).
    """

    name: ClassVar[str] = "quantisation"


@dataclass(frozen=True)
class TimestampWrap(Effect):
    """40-bit timestamp counters wrap every 2**40 units (17.2 s) [UM].

    On: recorded timestamps are modulo 2**40. Off: unwrapped (monotonic) integers, as some
    importers deliver; analyses take differences modulo 2**40 either way.
    """

    name: ClassVar[str] = "timestamp_wrap"


@dataclass(frozen=True)
class DelayedTxGrid(Effect):
    """Delayed TX ignores DX_TIME's low 9 bits: frames leave on a 512-unit (8.01 ns) grid [UM].

    TX_STAMP = (DX_TIME with the low 9 bits cleared) + TX_ANTD. Off: the frame leaves at the
    programmed unit (TX_STAMP = DX_TIME + TX_ANTD).
    """

    name: ClassVar[str] = "delayed_tx_grid"


@dataclass(frozen=True)
class AntennaDelay(Effect):
    """True TX/RX hardware delays differ from the programmed TX_ANTD / LDE_RXANTD registers.

    The RX stamp is taken at the arrival plus the true RX delay minus the programmed RX antenna
    delay; the frame leaves the antenna at the TX stamp's grid time plus the true TX delay,
    while TX_STAMP adds the programmed TX_ANTD. The station fields ``tx_delay_error_ps`` and
    ``rx_delay_error_ps`` are true minus programmed: the paper's constant Z. Source: [UM]
    TX_ANTD/LDE_RXANTD, [APS014]. Off: true delays equal the registers.
    """

    name: ClassVar[str] = "antenna_delay"


# --- radio -------------------------------------------------------------------------------


@dataclass(frozen=True)
class PathLoss(Effect):
    """Free-space path loss at the channel's centre frequency (Friis), or a cable's attenuation.

    Air: P_rx = P_tx + G_tx + G_rx - 10*exponent*log10(4*pi*d*f/c) dB (exponent 2 = Friis),
    at f = the channel frequency (3993.6 MHz for channel 2). Cable links: P_rx = P_tx -
    attenuation_db (the link's), delay = length / (velocity_factor * c). Source: [Friis].
    Off: the loss does not depend on distance: it is evaluated at ``ref_distance_m``.
    """

    name: ClassVar[str] = "path_loss"
    exponent: float = _p(2.0, "", "path-loss exponent (2 = free space)")
    ref_distance_m: float = _p(1.0, "m", "distance used when the effect is off")


@dataclass(frozen=True)
class TxGain(Effect):
    """TX_POWER gain octet -> actual gain: coarse steps (bits 7:5) and fine 0.5 dB steps (4:0).

    Nominal gain = fine * fine_step_db - coarse * coarse_step_db (coarse_step_db 3.0 in older
    manuals and public drivers, 2.5 in a later manual revision: a parameter). Actual gain adds
    per-station non-ideality: ``Station.coarse_errors_db[coarse]`` (dB, per coarse setting)
    and ``Station.fine_scale`` (actual/nominal fine step). Stations that do not give
    ``coarse_errors_db`` draw them from the scenario seed with ``coarse_sigma_db``. Source: [UM]
    TX_POWER. Off: actual gain = nominal.
    """

    name: ClassVar[str] = "tx_gain"
    coarse_step_db: float = _p(3.0, "dB", "true size of one coarse step (3.0 or 2.5)")
    fine_step_db: float = _p(0.5, "dB", "nominal size of one fine step")
    coarse_sigma_db: float = _p(0.3, "dB", "spread of drawn per-station coarse-step errors")


@dataclass(frozen=True)
class PowerBias(Effect):
    """Power-dependent RX timestamp error ("range bias"): a smooth sigmoid-like curve per station.

    range bias (m) at true RX level P (dBm): b(P) = c0 + a*tanh((p0 - x)/w) + s*(p0 - x) with
    x = P - Station.bias_shift_db; defaults are a least-squares fit to the APS011 64 MHz PRF
    table (dw1000.aps011_bias_m; RMS 1.9 mm, max 3.8 mm). Per timestamp the error is
    Station.bias_scale * b / c + Station.bias_offset_ps (a TWR range has two receptions, so
    its bias is c times one timestamp's error). Positive = late (range too long); stronger
    signals give earlier timestamps [paper]. Source: [APS011], [paper] section "Signal power
    correction". Off: no power-dependent error.
    """

    name: ClassVar[str] = "power_bias"
    c0_m: float = _p(-0.0211704948, "m", "curve offset")
    amplitude_m: float = _p(0.0406801865, "m", "tanh amplitude")
    centre_dbm: float = _p(-75.40523707, "dBm", "tanh centre p0")
    width_db: float = _p(4.02272782, "dB", "tanh width w")
    slope_m_per_db: float = _p(0.0035429429, "m/dB", "linear term s")


@dataclass(frozen=True)
class RxPowerEstimate(Effect):
    """The chip's RX level estimate under-reads strong signals (above about -85 dBm).

    est = P - (1 - high_slope) * knee_width_db * ln(1 + exp((P - knee_dbm) / knee_width_db))
    + N(0, noise_db): slope 1 well below the knee, ``high_slope`` well above it; strictly
    monotone, so invertible. The registers CIR_PWR and RXPACC are then produced so that
    dw1000.rx_level_dbm(CIR_PWR, RXPACC) gives ``est`` (to CIR_PWR's integer rounding), and
    FP_AMPL1..3 so that the first-path power is ``est - fp_delta_db``. A fraction
    ``sfd_in_rxpacc`` of receptions report RXPACC including the SFD symbols with RXPACC_NOSAT
    equal to it (the case the manual's correction is for; the others: RXPACC_NOSAT = RXPACC + 8,
    never equal). Source: [APS011]
    "estimated vs actual RX level", [paper] Fig. "Estimated RX level", [UM] 4.7.1-4.7.2.
    Off: est = P exactly (no compression, no noise).
    """

    name: ClassVar[str] = "rx_power_estimate"
    knee_dbm: float = _p(-80.0, "dBm", "centre of the compression knee")
    knee_width_db: float = _p(2.0, "dB", "softness of the knee")
    high_slope: float = _p(0.25, "dB/dB", "slope of the estimate far above the knee")
    noise_db: float = _p(0.2, "dB", "per-frame noise of the estimate")
    fp_delta_db: float = _p(2.0, "dB", "RX level minus first-path power in line of sight")
    std_noise: float = _p(50.0, "", "typical RX_FQUAL.STD_NOISE value")
    sfd_in_rxpacc: float = _p(
        0.0, "", "fraction of receptions whose RXPACC also counts the SFD symbols, shown by "
        "RXPACC_NOSAT equal to RXPACC [UM]: readers must subtract them (dw1000.rxpacc_n)")


@dataclass(frozen=True)
class CarIntError(Effect):
    """Carrier integrator DRX_CAR_INT: the true offset plus a power-dependent error plus noise.

    car_int = round(dw1000.ppm_to_car_int(-(offset_rx_minus_tx_ppm) + err)), err =
    Station.car_int_scale * slope_ppm_per_db * (P - ref_dbm) + N(0, noise_ppm), P the true RX
    power of the receiving station. A positive integrator means the receiver's clock runs fast
    [UM], so dw1000.car_int_to_ppm(car_int) reads the TX-minus-RX offset. Changing only the
    RX power moves it (the paper's jump). RX_TTCKO/RX_TTCKI carry the same offset without the
    power error: ttcko / ttcki = TX-minus-RX offset (ratio). Source: [paper] Fig. "Filtered
    integrator of the PLL", [UM] DRX_CAR_INT. Off: no power error and no noise.
    """

    name: ClassVar[str] = "car_int_error"
    slope_ppm_per_db: float = _p(0.02, "ppm/dB", "integrator error per dB of RX power")
    ref_dbm: float = _p(-80.0, "dBm", "RX power at which the power error is zero")
    noise_ppm: float = _p(0.05, "ppm", "per-frame noise of the integrator")


@dataclass(frozen=True)
class Interference(Effect):
    """Closely spaced messages disturb each other: a timestamp shift decaying with the gap.

    shift = amplitude_ps * exp(-gap / tau_s) added to a reception that follows the previous
    reception at the same receiver by ``gap`` (start to start). Defaults: at 150 us the shift
    is about 11 ps (3 mm, the paper's P1/P3 offset), at 2 ms 2e-6 ps (negligible).
    Source: [paper] Fig. "Short update time" (150 us against 2 ms); magnitude assumed.
    Off: no shift.
    """

    name: ClassVar[str] = "interference"
    amplitude_ps: float = _p(40.0, "ps", "shift at zero gap")
    tau_s: float = _p(120e-6, "s", "decay time of the disturbance")


@dataclass(frozen=True)
class Multipath(Effect):
    """Multipath / NLOS: with ``probability`` a reception's first path is late.

    The extra delay has mean ``mean_bias_m / c`` (positive range bias) and a gamma distribution of
    shape ``excess_shape`` (1: exponential, the default; larger: concentrated around the mean,
    as a log-normal excess is; smaller: more very late paths); such a reception's first-path
    power drops by ``fp_drop_db``. Source: common UWB NLOS models (e.g. IEEE 802.15.4a channel
    model: excess delay of the detected first path). Default off: the paper's lab set-ups are
    line of sight.
    """

    name: ClassVar[str] = "multipath"
    enabled: bool = False
    probability: float = _p(0.05, "", "probability of a late first path per reception")
    mean_bias_m: float = _p(0.10, "m", "mean extra path length of a late reception")
    fp_drop_db: float = _p(6.0, "dB", "first-path power drop of a late reception")
    excess_shape: float = _p(1.0, "", "gamma shape of the extra path length (1: exponential)")


#: Every effect by name, in the order the documentation lists them.
EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (
        ClockOffset,
        Warmup,
        ClockWander,
        Temperature,
        TimestampNoise,
        Quantisation,
        TimestampWrap,
        DelayedTxGrid,
        AntennaDelay,
        PathLoss,
        TxGain,
        PowerBias,
        RxPowerEstimate,
        CarIntError,
        Interference,
        Multipath,
    )
}


def default_effects() -> dict[str, Effect]:
    """One instance of every effect with its default switch and parameters."""
    return {name: cls() for name, cls in EFFECTS.items()}


def catalogue_markdown() -> str:
    """The catalogue as Markdown (name, switch default, parameters with units): for docs and --help."""
    lines: list[str] = []
    for name, cls in EFFECTS.items():
        doc = inspect.cleandoc(cls.__doc__ or "")
        default_on = "on" if cls().enabled else "off"
        lines.append(f"### `{name}` (default {default_on})\n\n{doc}\n")
        params = cls.parameters()
        if params:
            lines.append("| parameter | default | unit | meaning |\n|---|---|---|---|")
            for p, (d, unit, meaning) in params.items():
                lines.append(f"| `{p}` | {d:g} | {unit} | {meaning} |")
            lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":  # python -m uwbcal.physics.effects > catalogue for docs/PHYSICS.md
    print(catalogue_markdown())
