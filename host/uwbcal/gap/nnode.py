"""The believed world of a session with more stations than its scenario (N-node recordings).

A four-node asil run diagnosed against ``two_stations`` used to stop ("the session has stations
[0, 1, 2, 3] but the scenario only [1, 2]"). :func:`believed_world` builds the believed N-station
world itself instead: the scenario's stations first, unchanged, then one station per further
real station, added through :meth:`uwbcal.physics.scenario.Scenario.with_new_station`.

What is believed for a station nobody described:

- **hardware**: the catalogue's (the :class:`uwbcal.physics.scenario.Station` defaults): no
  warm-up, no tempco or self-heating, no antenna-delay errors, the reference power-bias curve,
  RX and TX noise scales 1, counter offset drawn from the scenario seed. Not copied from a
  described station: which described station an unknown board resembles is a guess, and a
  copied warm-up or bias curve would be a belief nobody held;
- **clock offset** (``ppm``): the one number the session itself fixes and a default cannot. A
  crystal's final offset is a per-unit constant of several ppm (+-10 ppm over units); believing
  0 ppm would be a made-up clock-rate gap of that size in every direction of the station, which
  the diagnosis would then "discover" and which would crowd out the effects it is there to name
  (only the second scenario station's offset is a candidate, :data:`uwbcal.gap.model.KNOBS`).
  So it is fitted to the session's own clock rates against the **reference** (the scenario's
  first station) and the other added stations only: one re-simulation of the session's schedule
  without clock wander, and one per added station with +1 ppm, give the rate's response; the
  offsets are the weighted least-squares solution of the per-direction median rate differences
  (real minus re-simulated). Directions with the other described stations are left out, so a
  wrong believed offset of those (the second station's) stays a gap the diagnosis can name
  instead of being shared out among the added stations. An added station whose only directions
  are with other described stations is fitted against those (said so in its note);
- **position**: used only where a record has no distance. Records carry the session's pair
  distances (the asil importer's ``node_pairs``: ``distance_m`` per record), which the
  re-simulated schedule uses as they are (:func:`uwbcal.vectorsim.schedule_from_records`);
  an added station is placed at the session's distance to the reference (2 m if none), each on
  its own bearing.

Real ids map onto scenario ids as before (:func:`uwbcal.gap.model.station_map`): equal ids when
the session's first ids are the scenario's (the added stations then keep the session's ids),
else in order (asil nodes 0..3 against two_stations: 0 -> 1, 1 -> 2, 2 -> 3, 3 -> 4, the first two
as in a two-node run).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np

from uwbcal.gap import model
from uwbcal.gap import observables as obs_mod
from uwbcal.physics.scenario import Scenario

#: Distance (m) of an added station from the reference when the session gives none.
DEFAULT_DISTANCE_M: Final = 2.0
#: Run seed of the re-simulations that fit the added stations' clock offsets.
FIT_SEED: Final = 1


@dataclass
class BelievedWorld:
    """The scenario the diagnosis believes in for a session, and what was added to it.

    ``scenario``: the given scenario, extended when the session has more stations; ``mapping``:
    real station id -> scenario station id; ``added``: one dict per added station (its scenario
    and real id, ``ppm`` and how it was fitted, ``position_m``, ``distance_to_reference_m``);
    ``reference``: the scenario station the clock offsets are fitted against.
    """

    scenario: Scenario
    mapping: dict[int, int]
    added: list[dict[str, Any]] = field(default_factory=list)
    reference: int | None = None

    def to_json(self) -> dict[str, Any]:
        """The ``stations_added`` entry of ``uwbcal gap --json``."""
        return {
            "scenario_stations": len(self.scenario.station_ids) - len(self.added),
            "session_stations": len(self.mapping),
            "real_to_scenario": {str(k): v for k, v in sorted(self.mapping.items())},
            "reference_station": self.reference,
            "believed_for_added": BELIEVED_FOR_ADDED,
            "added": self.added,
        }

    def describe(self) -> list[str]:
        """Plain lines for the text report: which stations were added, and with what."""
        if not self.added:
            return []
        n0 = len(self.scenario.station_ids) - len(self.added)
        real_of = {v: k for k, v in self.mapping.items()}
        ref_real = real_of.get(-1 if self.reference is None else self.reference)
        lines = [
            f"stations added: the session has {len(self.mapping)} stations, the scenario {n0}; "
            f"the believed world has {len(self.added)} more, with {BELIEVED_FOR_ADDED}",
            "  real -> scenario station: "
            + ", ".join(f"{k} -> {v}" for k, v in sorted(self.mapping.items())),
        ]
        for a in self.added:
            d = a["distance_to_reference_m"]
            lines.append(
                f"  added station {a['scenario_station']} (real {a['real_station']}): clock offset "
                f"{a['ppm']:+.4f} ppm ({a['ppm_from']}); {d:.3g} m from station {self.reference}"
                f" (real {ref_real})"
                + ("" if a["distance_from_session"] else " (no distance in the session)")
            )
        return lines


#: What the diagnosis believes about a station nobody described (the report says it).
BELIEVED_FOR_ADDED: Final = (
    "the catalogue's hardware (no warm-up, tempco or delay errors, reference bias curve, noise "
    "scales 1) and a clock offset fitted to the session's own clock rates"
)


#: Fewest time blocks (the attribution's cross-validation groups) an N-node session is cut into.
MIN_TIME_BLOCKS: Final = 4


def time_blocks(real: Mapping[str, Any], min_feature: int, default: int) -> int:
    """Time blocks (attribution groups) for a session: ``default``, unless three or more stations
    transmit and the lower quartile of the records per direction (tx -> rx) would leave fewer than
    ``min_feature`` records per direction and block; then as many blocks as give that many, at
    least :data:`MIN_TIME_BLOCKS`.

    A feature is one direction's records in one block (the spacing pooled, gap/observables.py),
    and one below ``min_feature`` records is dropped: a four-node run spreads its records over
    twelve directions, so 20 s of the real run 2026-02-24-01 (28..65 records per direction) had no
    feature left in 10 blocks and the attribution nothing to fit. Two-node sessions keep
    ``default`` (their diagnoses stay as they were).
    """
    tx = np.asarray(real["tx_station"])
    if np.unique(tx).size < 3:
        return default
    _, counts = np.unique(np.stack([tx, np.asarray(real["rx_station"])], axis=1), axis=0, return_counts=True)
    q25 = float(np.quantile(counts, 0.25))
    if q25 >= default * min_feature:
        return default
    return int(max(MIN_TIME_BLOCKS, min(default, q25 // min_feature)))


def _real_ids(real: Mapping[str, Any]) -> list[int]:
    return sorted({int(i) for col in ("tx_station", "rx_station") for i in np.asarray(real[col]).tolist()})


def _new_ids(real_ids: Sequence[int], sc_ids: Sequence[int]) -> list[int]:
    """Scenario ids of the stations to add: the session's own further ids when its first ids are
    the scenario's (stations 1, 2, 3, 4 against 1, 2: equal ids then map every station), else ids
    after the scenario's largest, so that the session's stations map in order (asil nodes 0..3
    against 1, 2: nodes 0 and 1 are the scenario's stations, as in a two-node run)."""
    extra = len(real_ids) - len(sc_ids)
    if sorted(real_ids)[: len(sc_ids)] == sorted(sc_ids):
        return sorted(real_ids)[len(sc_ids) :]
    top = max(sc_ids)
    return [top + 1 + j for j in range(extra)]


def _pair_distance(real: Mapping[str, Any], a: int, b: int) -> float:
    """Median recorded distance (m) of the real pair (a, b), either direction; nan if none."""
    d = real.get("distance_m")
    if d is None:
        return float("nan")
    tx, rx = np.asarray(real["tx_station"]), np.asarray(real["rx_station"])
    sel = ((tx == a) & (rx == b)) | ((tx == b) & (rx == a))
    v = np.asarray(d, np.float64)[sel]
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else float("nan")


def believed_world(real: Mapping[str, Any], scenario: Scenario, prf_mhz: int = 64) -> BelievedWorld:
    """The believed world of a session (module docstring); unchanged when the scenario has as many
    stations as the session or more. ``real``: triplet records (columns by name, ``t_s`` as the
    diagnosis uses it); ``prf_mhz``: the session's PRF, for the observables."""
    real_ids = _real_ids(real)
    sc_ids = scenario.station_ids
    if len(real_ids) <= len(sc_ids):
        return BelievedWorld(scenario, model.station_map(real_ids, scenario))
    new = _new_ids(real_ids, sc_ids)
    ref = sc_ids[0]
    sc = scenario
    placed: list[tuple[int, float, bool]] = []
    for sid in new:
        sc = sc.with_new_station(sid)
    mapping = model.station_map(real_ids, sc)
    real_of = {v: k for k, v in mapping.items()}
    ref_pos = np.asarray(scenario.station(ref).position_m, np.float64)
    for j, sid in enumerate(new):
        d = _pair_distance(real, real_of[sid], real_of[ref])
        known = bool(np.isfinite(d) and d > 0)
        dist = d if known else DEFAULT_DISTANCE_M
        # each added station on its own bearing (quarter turns from +y), in the reference's plane
        ang = math.pi / 2.0 * (j + 1)
        pos = ref_pos + dist * np.array([math.cos(ang), math.sin(ang), 0.0])
        sc = sc.with_station(sid, position_m=tuple(float(x) for x in pos))
        placed.append((sid, dist, known))
    ppm, how = _fit_offsets(real, sc, new, ref, mapping, prf_mhz)
    for sid in new:
        sc = sc.with_station(sid, ppm=ppm[sid])
    added = [
        {
            "scenario_station": sid,
            "real_station": real_of[sid],
            "ppm": ppm[sid],
            "ppm_from": how[sid],
            "position_m": list(sc.station(sid).position_m),
            "distance_to_reference_m": dist,
            "distance_from_session": known,
        }
        for sid, dist, known in placed
    ]
    return BelievedWorld(sc, mapping, added, ref)


def _fit_offsets(
    real: Mapping[str, Any],
    sc: Scenario,
    new: Sequence[int],
    ref: int,
    mapping: Mapping[int, int],
    prf_mhz: int,
) -> tuple[dict[int, float], dict[int, str]]:
    """Clock offsets (ppm) of the added stations ``new`` from the session's clock rates (module
    docstring), and per station how: ({scenario id: ppm}, {scenario id: note})."""
    if not sc.enabled("clock_offset"):
        return {s: 0.0 for s in new}, {s: "0: the scenario switches clock offsets off" for s in new}
    quiet = sc.with_effects(enabled={"clock_wander": False})
    sim = model.physics_simulator(real, quiet)

    def rate(rec: Mapping[str, Any]) -> Any:
        return obs_mod.observables(rec, prf_mhz).get("clock_rate_ppm")

    r_real = rate(real)
    r0 = rate(sim((), FIT_SEED))
    if r_real is None or r0 is None:
        return {s: 0.0 for s in new}, {s: "0: no clock rate in the session" for s in new}
    resp = {s: rate(sim(((f"station:{s}:ppm", float(sc.station(s).ppm) + 1.0),), FIT_SEED)) for s in new}
    tx = np.asarray([mapping[int(i)] for i in np.asarray(real["tx_station"]).tolist()])
    rx = np.asarray([mapping[int(i)] for i in np.asarray(real["rx_station"]).tolist()])
    pairs = sorted({(int(a), int(b)) for a, b in zip(tx, rx, strict=True)})

    def solve(anchors: set[int]) -> tuple[np.ndarray, int, list[tuple[int, int]]]:
        rows, rhs, w, used = [], [], [], []
        for a, b in pairs:
            if not ({a, b} <= anchors | set(new)) or not ({a, b} & set(new)):
                continue
            sel = (tx == a) & (rx == b) & np.isfinite(r_real) & np.isfinite(r0)
            if np.count_nonzero(sel) < 3:
                continue
            rows.append([float(np.median(resp[s][sel] - r0[sel])) for s in new])
            rhs.append(float(np.median(r_real[sel] - r0[sel])))
            w.append(math.sqrt(float(np.count_nonzero(sel))))
            used.append((a, b))
        if not rows:
            return np.zeros(len(new)), 0, used
        x = np.asarray(rows) * np.asarray(w)[:, None]
        y = np.asarray(rhs) * np.asarray(w)
        sol, _, rank, _ = np.linalg.lstsq(x, y, rcond=None)
        return np.asarray(sol, np.float64), int(rank), used

    inverse = {v: k for k, v in mapping.items()}
    sol, rank, used = solve({ref})
    against = f"station {ref} (real {inverse[ref]})"
    if rank < len(new):  # an added station without a direction to the reference: all described ones
        described = {s for s in sc.station_ids if s not in new}
        sol, rank, used = solve(described)
        against = "the described stations " + ", ".join(f"{s} (real {inverse[s]})" for s in sorted(described))
    ppm: dict[int, float] = {}
    how: dict[int, str] = {}
    for k, s in enumerate(new):
        seen = sum(1 for a, b in used if s in (a, b))
        if rank < len(new) and seen == 0:
            ppm[s], how[s] = 0.0, "0: no direction links it to a described station"
            continue
        ppm[s] = float(sc.station(s).ppm + sol[k])
        how[s] = f"fitted to {seen} directions' clock rates against {against}"
    return ppm, how
