"""Sim-to-real gap diagnosis: where real sessions differ from the simulation, which catalogue
effect causes it, and how far the gap shrinks with it (docs/GAP.md).

- :mod:`uwbcal.gap.engine`: runs the steps in order (independent of the physics):
  :mod:`~uwbcal.gap.localise` (where), :mod:`~uwbcal.gap.features` (per-group features),
  :mod:`~uwbcal.gap.attribute` (which effect), :mod:`~uwbcal.gap.quantify` (how far);
  :mod:`~uwbcal.gap.pool` runs the simulations, :mod:`~uwbcal.gap.config` holds the settings;
- :mod:`uwbcal.gap.stats`: the statistics on plain arrays (BH-FDR, floor p-values, features,
  Lasso, bootstrap);
- :mod:`uwbcal.gap.observables`: observables and regimes of triplet records;
- :mod:`uwbcal.gap.model`: knobs, candidates and re-simulation through the physics catalogue;
- :mod:`uwbcal.gap.validate`: trials with a known withheld cause (`uwbcal gap validate`);
- :mod:`uwbcal.gap.report`: text and plots.
"""
