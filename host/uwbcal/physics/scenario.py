"""Scenarios: the stations, links, radio settings, effects and seed of a simulated world.

A scenario is a TOML file (format in docs/SCENARIOS.md; examples in the repo's scenarios/)
loaded by :func:`load_scenario` into an immutable :class:`Scenario`. Change one
programmatically with :meth:`Scenario.with_effects`, :meth:`Scenario.with_station` and
:meth:`Scenario.with_seed`; :meth:`Scenario.to_toml` writes it back (sessions store that text).

Units: positions and lengths m, frequency offsets ppm (+ = the station's clock runs fast),
times s, antenna-delay registers device units (15.65 ps), delay errors ps, powers dBm,
gains dB, temperatures degC.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uwbcal import dw1000
from uwbcal.errors import ScenarioError
from uwbcal.physics.effects import EFFECTS, Effect, default_effects

#: Where the example scenarios live in a source tree (repo/scenarios).
REPO_SCENARIOS = Path(__file__).resolve().parents[3] / "scenarios"

_RATES = dw1000.DATA_RATES_KBPS


@dataclass(frozen=True)
class Radio:
    """Radio configuration shared by all stations (the paper's: channel 2, 64 MHz PRF, 128, 6.81 Mb/s)."""

    channel: int = 2
    prf_mhz: int = 64
    preamble_length: int = 128
    data_rate_kbps: int = 6810

    @property
    def freq_hz(self) -> float:
        """Carrier centre frequency, Hz (dw1000.CHANNEL_FREQ_HZ)."""
        return dw1000.CHANNEL_FREQ_HZ[self.channel]


@dataclass(frozen=True)
class Station:
    """One station's hardware. Values an effect governs are ignored while that effect is off.

    Attributes (units): ``id`` station id; ``uid`` device UID string; ``position_m`` (x, y, z) m;
    ``ppm`` final clock frequency offset, ppm (+ fast) [clock_offset]; ``warmup_ppm`` offset at
    power-on relative to the final one, ppm, ``warmup_tau_s`` its time constant, s, and
    ``warmup2_ppm``, ``warmup2_tau_s`` a second stage of it (a crystal that settles in two time
    constants: its oven and its board heat; 0 ppm: one stage) [warmup];
    ``power_on_s`` true time of power-on relative to the session start, s (negative: before);
    ``counter_offset_units`` system-time counter at power-on, units (None: drawn from the seed);
    ``tempco_ppm_per_c``, ``ambient_c``, ``self_heating_c`` [temperature]; ``tx_antd``,
    ``rx_antd`` programmed antenna delay registers, units; ``tx_delay_error_ps``,
    ``rx_delay_error_ps`` true hardware delay minus the register, ps [antenna_delay];
    ``tx_ref_dbm`` TX output power at nominal gain 0 dB (coarse 0, fine 0), dBm;
    ``antenna_gain_dbi``; ``bias_scale``, ``bias_shift_db``, ``bias_offset_ps`` the station's
    power-bias curve [power_bias]; ``coarse_errors_db`` 7 per-coarse-setting gain errors, dB
    (None: drawn) and ``fine_scale`` actual/nominal fine step [tx_gain]; ``car_int_scale``
    scale of its integrator's power error [car_int_error]; ``noise_scale`` factor (>= 0,
    dimensionless) on the RX timestamp jitter sigma of this station's receptions
    [timestamp_noise] (1: the catalogue's sigma; receivers of one type differ, e.g. the asil
    run's two nodes by about 1.8, docs/GAP.md); ``tx_noise_scale`` factor (>= 0, dimensionless)
    on the TX jitter sigma (``tx_jitter_ps``) of this station's emissions [timestamp_noise]
    (1: the catalogue's; with three or more stations a noisier transmitter and a noisier
    receiver give different records, docs/GAP.md "N-node gap").
    """

    id: int
    name: str = ""
    uid: str = ""
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ppm: float = 0.0
    warmup_ppm: float = 0.0
    warmup_tau_s: float = 200.0
    warmup2_ppm: float = 0.0
    warmup2_tau_s: float = 20.0
    power_on_s: float = 0.0
    counter_offset_units: int | None = None
    tempco_ppm_per_c: float = 0.0
    ambient_c: float = 25.0
    self_heating_c: float = 0.0
    tx_antd: int = 16436
    rx_antd: int = 16436
    tx_delay_error_ps: float = 0.0
    rx_delay_error_ps: float = 0.0
    tx_ref_dbm: float = -30.0
    antenna_gain_dbi: float = 0.0
    bias_scale: float = 1.0
    bias_shift_db: float = 0.0
    bias_offset_ps: float = 0.0
    coarse_errors_db: tuple[float, ...] | None = None
    fine_scale: float = 1.0
    car_int_scale: float = 1.0
    noise_scale: float = 1.0
    tx_noise_scale: float = 1.0
    board: str = "native"      #: what runs the firmware-in-the-loop station: one of BOARDS


#: Boards a firmware-in-the-loop station can be (``board`` key of a station): the native build
#: (uwbcal-station) or the EVK1000 image in the emulator (uwbcal.evk1000).
BOARDS: tuple[str, ...] = ("native", "evk1000")


@dataclass(frozen=True)
class Link:
    """A link between stations ``a`` and ``b`` overriding free space.

    ``kind`` "air" (Friis at the geometry's or a schedule's distance, plus ``extra_loss_db``)
    or "cable" (``length_m`` m of cable with ``attenuation_db`` dB total loss and signal speed
    ``velocity_factor`` * c; no antennas).
    """

    a: int
    b: int
    kind: str = "air"
    length_m: float | None = None
    attenuation_db: float = 0.0
    velocity_factor: float = 0.7
    extra_loss_db: float = 0.0


@dataclass(frozen=True)
class Move:
    """A scripted move: at true time ``t_s`` (s from the session start) station ``station``
    goes to ``position_m`` (x, y, z), m. The firmware-in-the-loop medium plays moves as virtual
    time passes them; the vectorised simulator takes its distances from its schedule instead."""

    t_s: float
    station: int
    position_m: tuple[float, float, float]


@dataclass(frozen=True)
class Scenario:
    """A whole simulated world: stations, links, radio, effects (by name), scripted moves
    (sorted by time) and the seed."""

    name: str = "scenario"
    description: str = ""
    seed: int = 1
    radio: Radio = field(default_factory=Radio)
    stations: tuple[Station, ...] = ()
    links: tuple[Link, ...] = ()
    effects: Mapping[str, Effect] = field(default_factory=default_effects)
    source: str = ""
    moves: tuple[Move, ...] = ()

    # -- queries --------------------------------------------------------------------------
    def station(self, station_id: int) -> Station:
        """The station with this id; ScenarioError if there is none."""
        for s in self.stations:
            if s.id == station_id:
                return s
        raise ScenarioError(
            f"scenario {self.name!r} has no station {station_id} (stations: {[s.id for s in self.stations]})"
        )

    @property
    def station_ids(self) -> list[int]:
        """Station ids in file order."""
        return [s.id for s in self.stations]

    def link(self, a: int, b: int) -> Link:
        """The link between two stations (either order): the file's, else free space."""
        for lk in self.links:
            if {lk.a, lk.b} == {a, b}:
                return lk
        return Link(a=a, b=b)

    def distance_m(self, a: int, b: int) -> float:
        """Nominal distance, m: a link's ``length_m`` if given, else between the positions."""
        lk = self.link(a, b)
        if lk.length_m is not None:
            return float(lk.length_m)
        pa, pb = self.station(a).position_m, self.station(b).position_m
        return float(math.dist(pa, pb))

    def enabled(self, effect: str) -> bool:
        """Whether the named effect is switched on."""
        return self.effects[effect].enabled

    def effect(self, name: str) -> Effect:
        """The named effect's instance; ScenarioError for an unknown name."""
        if name not in self.effects:
            raise ScenarioError(f"unknown effect {name!r} (known: {', '.join(EFFECTS)})")
        return self.effects[name]

    # -- programmatic changes -------------------------------------------------------------
    def with_effects(
        self,
        enabled: Mapping[str, bool] | None = None,
        params: Mapping[str, Mapping[str, float]] | None = None,
    ) -> Scenario:
        """A copy with effects switched (``{"warmup": False}``) and parameters overridden
        (``{"interference": {"amplitude_ps": 20.0}}``); ScenarioError names a bad key/value."""
        effects = dict(self.effects)
        for name in set(enabled or {}) | set(params or {}):
            if name not in EFFECTS:
                raise ScenarioError(f"unknown effect {name!r} (known: {', '.join(EFFECTS)})")
            on = (enabled or {}).get(name)
            effects[name] = effects[name].replace(enabled=on, **dict((params or {}).get(name, {})))
        return dataclasses.replace(self, effects=effects)

    def with_all_effects(self, enabled: bool) -> Scenario:
        """A copy with every effect switched on or off (parameters kept)."""
        return self.with_effects(enabled={n: enabled for n in EFFECTS})

    def with_station(self, station_id: int, **changes: Any) -> Scenario:
        """A copy with one station's fields changed (``with_station(2, ppm=5.0)``)."""
        self.station(station_id)
        names = {f.name for f in dataclasses.fields(Station)}
        for key in changes:
            if key not in names or key == "id":
                raise ScenarioError(f"station {station_id}: unknown or fixed field {key!r}")
        stations = tuple(
            _check_station(dataclasses.replace(s, **changes)) if s.id == station_id else s
            for s in self.stations
        )
        return dataclasses.replace(self, stations=stations)

    def with_new_station(self, station_id: int, **fields: Any) -> Scenario:
        """A copy with one more station, last in file order (``with_new_station(3, ppm=2.0)``).

        Fields not given take the :class:`Station` defaults (the catalogue's hardware: no clock
        offset or warm-up, no delay errors, the reference power-bias curve, noise scales 1); the
        uid and name default as in a scenario file (``SIM-0003``, ``station3``). ScenarioError for
        an id already present or a bad field, as :meth:`with_station`.
        """
        if station_id in self.station_ids:
            raise ScenarioError(f"scenario {self.name!r} already has a station {station_id}")
        names = {f.name for f in dataclasses.fields(Station)}
        for key in fields:
            if key not in names or key == "id":
                raise ScenarioError(f"station {station_id}: unknown or fixed field {key!r}")
        kw = {"uid": f"SIM-{station_id:04d}", "name": f"station{station_id}", **fields}
        if "position_m" in kw:
            kw["position_m"] = tuple(float(x) for x in kw["position_m"])
        st = _check_station(Station(id=int(station_id), **kw))
        return dataclasses.replace(self, stations=(*self.stations, st))

    def with_seed(self, seed: int) -> Scenario:
        """A copy with another seed (the hardware draws and the default run seed)."""
        return dataclasses.replace(self, seed=int(seed))

    # -- serialisation --------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """A JSON/TOML-able dict in the file format (None values left out)."""
        out: dict[str, Any] = {
            "name": self.name,
            "description": self.description,
            "seed": self.seed,
            "radio": dataclasses.asdict(self.radio),
        }
        out["stations"] = [_drop_none(dataclasses.asdict(s)) for s in self.stations]
        out["links"] = [_drop_none(dataclasses.asdict(lk)) for lk in self.links]
        out["effects"] = {n: {"enabled": e.enabled, **e.values()} for n, e in self.effects.items()}
        out["moves"] = [{"t_s": m.t_s, "station": m.station, "position_m": list(m.position_m)}
                        for m in self.moves]
        return out

    def to_toml(self) -> str:
        """The scenario as TOML text that :func:`parse_scenario` reads back to an equal scenario."""
        d = self.to_dict()
        lines = [
            f"name = {_toml_value(d['name'])}",
            f"description = {_toml_value(d['description'])}",
            f"seed = {d['seed']}",
            "",
            "[radio]",
        ]
        lines += [f"{k} = {_toml_value(v)}" for k, v in d["radio"].items()]
        for s in d["stations"]:
            lines += ["", "[[stations]]"] + [f"{k} = {_toml_value(v)}" for k, v in s.items()]
        for lk in d["links"]:
            lines += ["", "[[links]]"] + [f"{k} = {_toml_value(v)}" for k, v in lk.items()]
        for n, e in d["effects"].items():
            lines += ["", f"[effects.{n}]"] + [f"{k} = {_toml_value(v)}" for k, v in e.items()]
        for mv in d["moves"]:
            lines += ["", "[[moves]]"] + [f"{k} = {_toml_value(v)}" for k, v in mv.items()]
        return "\n".join(lines) + "\n"


def _drop_none(d: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in d.items() if v is not None}


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("inf" if v > 0 else "-inf") if not math.isnan(v) else "nan"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


# --- loading -----------------------------------------------------------------------------


def _num(where: str, value: Any, *, integer: bool = False) -> Any:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(f"{where}: expected a number, got {value!r}")
    if integer:
        if isinstance(value, float) and not value.is_integer():
            raise ScenarioError(f"{where}: expected an integer, got {value!r}")
        return int(value)
    if not math.isfinite(float(value)):
        raise ScenarioError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _fields_from(
    cls: type[Any], where: str, raw: Mapping[str, Any], required: tuple[str, ...] = ()
) -> dict[str, Any]:
    fields = {f.name: f for f in dataclasses.fields(cls)}
    out: dict[str, Any] = {}
    for key in required:
        if key not in raw:
            raise ScenarioError(f"{where}: missing key {key!r}")
    for key, value in raw.items():
        if key not in fields:
            raise ScenarioError(f"{where}: unknown key {key!r} (known: {', '.join(fields)})")
        default = fields[key].default
        typ = str(fields[key].type)
        loc = f"{where}.{key}"
        if typ == "str":
            if not isinstance(value, str):
                raise ScenarioError(f"{loc}: expected a string, got {value!r}")
            out[key] = value
        elif typ == "int":
            out[key] = _num(loc, value, integer=True)
        elif typ == "int | None":
            out[key] = _num(loc, value, integer=True)
        elif typ == "float" or typ == "float | None":
            out[key] = _num(loc, value)
        elif typ.startswith("tuple"):
            if not isinstance(value, list):
                raise ScenarioError(f"{loc}: expected an array of numbers, got {value!r}")
            out[key] = tuple(_num(f"{loc}[{i}]", x) for i, x in enumerate(value))
        else:  # pragma: no cover - a new field type must be handled above
            raise ScenarioError(f"{loc}: unsupported field type {typ} (default {default!r})")
    return out


def _check_station(s: Station) -> Station:
    where = f"stations[id={s.id}]"
    if len(s.position_m) != 3:
        raise ScenarioError(f"{where}.position_m: expected [x, y, z] in m, got {list(s.position_m)}")
    if s.coarse_errors_db is not None and len(s.coarse_errors_db) != 7:
        raise ScenarioError(
            f"{where}.coarse_errors_db: expected 7 values (coarse 0..6), got {len(s.coarse_errors_db)}"
        )
    if s.warmup_tau_s <= 0:
        raise ScenarioError(f"{where}.warmup_tau_s: must be > 0 s, got {s.warmup_tau_s}")
    if s.warmup2_tau_s <= 0:
        raise ScenarioError(f"{where}.warmup2_tau_s: must be > 0 s, got {s.warmup2_tau_s}")
    if s.fine_scale <= 0:
        raise ScenarioError(f"{where}.fine_scale: must be > 0, got {s.fine_scale}")
    if s.board not in BOARDS:
        raise ScenarioError(f"{where}.board: expected one of {', '.join(BOARDS)}, got {s.board!r}")
    if not s.noise_scale >= 0 or not math.isfinite(s.noise_scale):
        raise ScenarioError(f"{where}.noise_scale: must be a finite number >= 0, got {s.noise_scale}")
    if not s.tx_noise_scale >= 0 or not math.isfinite(s.tx_noise_scale):
        raise ScenarioError(f"{where}.tx_noise_scale: must be a finite number >= 0, got {s.tx_noise_scale}")
    if abs(s.ppm) > 1000 or abs(s.warmup_ppm) > 1000 or abs(s.warmup2_ppm) > 1000:
        raise ScenarioError(f"{where}: clock offset beyond 1000 ppm is not a crystal")
    if s.counter_offset_units is not None and not 0 <= s.counter_offset_units < dw1000.TIMESTAMP_MOD:
        raise ScenarioError(f"{where}.counter_offset_units: must be in [0, 2**40)")
    return s


def parse_scenario(text: str, name: str = "scenario") -> Scenario:
    """A Scenario from TOML text; ScenarioError names the bad key or value."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{name}: not valid TOML: {exc}") from None
    known = {"name", "description", "seed", "radio", "stations", "links", "effects", "moves"}
    for key in raw:
        if key not in known:
            raise ScenarioError(f"{name}: unknown top-level key {key!r} (known: {', '.join(sorted(known))})")
    sc_name = raw.get("name", name)
    if not isinstance(sc_name, str):
        raise ScenarioError(f"{name}.name: expected a string, got {sc_name!r}")
    desc = raw.get("description", "")
    if not isinstance(desc, str):
        raise ScenarioError(f"{name}.description: expected a string, got {desc!r}")
    seed = _num(f"{name}.seed", raw.get("seed", 1), integer=True)
    if seed < 0:
        raise ScenarioError(f"{name}.seed: must be >= 0, got {seed}")

    radio_raw = raw.get("radio", {})
    if not isinstance(radio_raw, dict):
        raise ScenarioError(f"{name}.radio: expected a table")
    radio = Radio(**_fields_from(Radio, "radio", radio_raw))
    if radio.channel not in dw1000.CHANNEL_FREQ_HZ:
        raise ScenarioError(
            f"radio.channel: {radio.channel} is not a DW1000 channel ({sorted(dw1000.CHANNEL_FREQ_HZ)})"
        )
    if radio.prf_mhz not in dw1000.RX_LEVEL_A_DBM:
        raise ScenarioError(f"radio.prf_mhz: {radio.prf_mhz} (expected 16 or 64)")
    if radio.preamble_length not in dw1000.PREAMBLE_LENGTHS:
        raise ScenarioError(
            f"radio.preamble_length: {radio.preamble_length} (expected one of {dw1000.PREAMBLE_LENGTHS})")
    if radio.data_rate_kbps not in _RATES:
        raise ScenarioError(f"radio.data_rate_kbps: {radio.data_rate_kbps} (expected one of {_RATES})")

    st_raw = raw.get("stations", [])
    if not isinstance(st_raw, list) or not st_raw:
        raise ScenarioError(f"{name}: at least one [[stations]] entry is needed")
    stations: list[Station] = []
    for i, s in enumerate(st_raw):
        if not isinstance(s, dict):
            raise ScenarioError(f"stations[{i}]: expected a table")
        kw = _fields_from(Station, f"stations[{i}]", s, required=("id",))
        if "position_m" in kw and len(kw["position_m"]) != 3:
            raise ScenarioError(f"stations[{i}].position_m: expected [x, y, z] in m")
        kw.setdefault("uid", f"SIM-{kw['id']:04d}")
        kw.setdefault("name", f"station{kw['id']}")
        stations.append(_check_station(Station(**kw)))
    ids = [s.id for s in stations]
    if len(set(ids)) != len(ids):
        raise ScenarioError(f"stations: duplicate id in {ids}")

    links: list[Link] = []
    for i, lk in enumerate(raw.get("links", [])):
        if not isinstance(lk, dict):
            raise ScenarioError(f"links[{i}]: expected a table")
        link = Link(**_fields_from(Link, f"links[{i}]", lk, required=("a", "b")))
        if link.kind not in ("air", "cable"):
            raise ScenarioError(f"links[{i}].kind: {link.kind!r} (expected 'air' or 'cable')")
        for end in (link.a, link.b):
            if end not in ids:
                raise ScenarioError(f"links[{i}]: station {end} is not in stations {ids}")
        if link.kind == "cable" and link.length_m is None:
            raise ScenarioError(f"links[{i}]: a cable needs length_m")
        if not 0 < link.velocity_factor <= 1:
            raise ScenarioError(f"links[{i}].velocity_factor: must be in (0, 1], got {link.velocity_factor}")
        links.append(link)

    effects = default_effects()
    eff_raw = raw.get("effects", {})
    if not isinstance(eff_raw, dict):
        raise ScenarioError(f"{name}.effects: expected a table of effect tables")
    for en, params in eff_raw.items():
        if en not in EFFECTS:
            raise ScenarioError(f"effects.{en}: unknown effect (known: {', '.join(EFFECTS)})")
        if not isinstance(params, dict):
            raise ScenarioError(f"effects.{en}: expected a table")
        p = dict(params)
        on = p.pop("enabled", None)
        try:
            effects[en] = effects[en].replace(enabled=on, **p)
        except ScenarioError as exc:
            raise ScenarioError(f"effects.{en}: {exc}") from None
    moves: list[Move] = []
    mv_raw = raw.get("moves", [])
    if not isinstance(mv_raw, list):
        raise ScenarioError(f"{name}.moves: expected [[moves]] tables")
    for i, mv in enumerate(mv_raw):
        if not isinstance(mv, dict) or set(mv) != {"t_s", "station", "position_m"}:
            raise ScenarioError(f"moves[{i}]: expected t_s (s), station (id) and position_m ([x, y, z] m), "
                                f"got {sorted(mv) if isinstance(mv, dict) else mv!r}")
        t = _num(f"moves[{i}].t_s", mv["t_s"])
        sid = _num(f"moves[{i}].station", mv["station"], integer=True)
        pos = mv["position_m"]
        if not isinstance(pos, list) or len(pos) != 3:
            raise ScenarioError(f"moves[{i}].position_m: expected [x, y, z] in m, got {pos!r}")
        if sid not in ids:
            raise ScenarioError(f"moves[{i}].station: {sid} is not in stations {ids}")
        if t < 0:
            raise ScenarioError(f"moves[{i}].t_s: must be >= 0, got {t}")
        xyz = tuple(_num(f"moves[{i}].position_m", v) for v in pos)
        moves.append(Move(t_s=float(t), station=int(sid),
                          position_m=(float(xyz[0]), float(xyz[1]), float(xyz[2]))))
    return Scenario(
        name=sc_name,
        description=desc,
        seed=seed,
        radio=radio,
        stations=tuple(stations),
        links=tuple(links),
        effects=effects,
        source=text,
        moves=tuple(sorted(moves, key=lambda m: m.t_s)),
    )


def find_scenario(name_or_path: str | Path) -> Path:
    """A scenario file: an existing path, or the name of an example (``paper_cable``) in the
    repo's scenarios/ or the package's ``uwbcal/scenarios``; ScenarioError if none."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    stem = p.name if p.suffix == ".toml" else p.name + ".toml"
    candidates = [REPO_SCENARIOS / stem, Path(__file__).resolve().parents[1] / "scenarios" / stem]
    for c in candidates:
        if c.is_file():
            return c
    raise ScenarioError(f"no scenario file {str(name_or_path)!r} (examples: {', '.join(list_scenarios())})")


def list_scenarios() -> list[str]:
    """Names of the example scenarios found (repo scenarios/ or package data)."""
    names: set[str] = set()
    for d in (REPO_SCENARIOS, Path(__file__).resolve().parents[1] / "scenarios"):
        if d.is_dir():
            names.update(f.stem for f in d.glob("*.toml"))
    return sorted(names)


def load_scenario(path: str | Path) -> Scenario:
    """Load a scenario from a TOML file path or an example's name; ScenarioError on any problem."""
    p = find_scenario(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{p}: cannot read: {exc}") from None
    return parse_scenario(text, name=p.stem)
