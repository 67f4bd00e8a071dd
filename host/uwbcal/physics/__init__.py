"""The world model: clocks, propagation, received power, timestamp bias, as a catalogue of
named, switchable, parameterised effects. The vectorised simulator (uwbcal.vectorsim) and the
simulated medium (uwbcal.medium) both call it: one implementation of the physics.

Public API:
- :func:`load_scenario`, :func:`parse_scenario`, :func:`find_scenario`, :func:`list_scenarios`,
  :class:`Scenario` (``with_effects``, ``with_station``, ``with_seed``, ``to_toml``),
  :class:`Station`, :class:`Link`, :class:`Radio`;
- :data:`EFFECTS` (name -> effect class), :class:`Effect`;
- :class:`World` (clocks true<->local, ``delayed_tx``, ``receive``, per-frame ``transmit``),
  :class:`TxBatch`, :class:`RxBatch`, :class:`Reception`, :func:`reception_gaps`.
See docs/PHYSICS.md and docs/SCENARIOS.md.
"""

from uwbcal.physics.effects import EFFECTS, Effect, catalogue_markdown, default_effects
from uwbcal.physics.scenario import (
    Link,
    Radio,
    Scenario,
    Station,
    find_scenario,
    list_scenarios,
    load_scenario,
    parse_scenario,
)
from uwbcal.physics.world import Reception, RxBatch, StationClock, TxBatch, World, reception_gaps

__all__ = [
    "EFFECTS",
    "Effect",
    "Link",
    "Radio",
    "Reception",
    "RxBatch",
    "Scenario",
    "Station",
    "StationClock",
    "TxBatch",
    "World",
    "catalogue_markdown",
    "default_effects",
    "find_scenario",
    "list_scenarios",
    "load_scenario",
    "parse_scenario",
    "reception_gaps",
]
