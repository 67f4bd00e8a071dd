"""Sim-to-real gap diagnosis: where real sessions differ from the simulation, which catalogue
effect causes it, and how far the gap shrinks with it (docs/GAP.md).

- :mod:`uwbcal.gap.engine`: localise, attribute, quantify (independent of the physics);
- :mod:`uwbcal.gap.stats`: the statistics on plain arrays (BH-FDR, floor p-values, features,
  Lasso, bootstrap);
- :mod:`uwbcal.gap.observables`: observables and regimes of triplet records;
- :mod:`uwbcal.gap.model`: knobs, candidates and re-simulation through the physics catalogue;
- :mod:`uwbcal.gap.validate`: trials with a known withheld cause (`uwbcal gap validate`);
- :mod:`uwbcal.gap.report`: text and plots.
"""
