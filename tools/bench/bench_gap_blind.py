"""Benchmark: the gap diagnosis against independent departures (issue 13's bars), beside the old
self-generated validation.

`python tools/bench/bench_gap_blind.py [TRIALS] [SEED] [--json out.json] [--blind-only]`: runs
:func:`uwbcal.gap.blind.validate_blind` (default 40 trials, seed 0, 2 workers: two-way asil-like
sessions through the asil importer, and power sweeps; singles, nulls, pairs, decoys) and
:func:`uwbcal.gap.validate.validate` on the same number of trials, and prints the figures per
session form with the bars (``--blind-only``: without the old validation). Takes several
minutes on 2 cores (not part of `make test`). With ``--json out.json`` each trial's result is
also appended to ``out.json.partial`` (JSON lines) as it finishes, so a stopped run keeps its
trials (:func:`uwbcal.gap.blind.summarise` scores them).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path


def _p(x: float) -> str:
    return "n/a" if x != x else f"{100 * x:.0f}%"


def main(argv: list[str]) -> int:
    from uwbcal.gap import blind, validate

    out = None
    if "--json" in argv:
        i = argv.index("--json")
        out = Path(argv[i + 1])
        argv = argv[:i] + argv[i + 2 :]
    blind_only = "--blind-only" in argv
    argv = [a for a in argv if a != "--blind-only"]
    n = int(argv[0]) if argv else 40
    seed = int(argv[1]) if len(argv) > 1 else 0
    jobs = min(2, os.cpu_count() or 1)
    partial = None if out is None else out.with_name(out.name + ".partial")
    if partial is not None:
        partial.write_text("")

    def keep(r: dict[str, object]) -> None:
        if partial is not None:
            with partial.open("a") as f:
                f.write(json.dumps(r, default=str) + "\n")

    t0 = time.perf_counter()
    res = blind.validate_blind(
        n_trials=n, seed=seed, jobs=jobs, progress=lambda m: print(m, flush=True), on_result=keep
    )
    t_blind = time.perf_counter() - t0
    t0 = time.perf_counter()
    old = None if blind_only else validate.validate(n_trials=n, seed=seed, jobs=jobs)
    t_old = time.perf_counter() - t0
    for name, f in [("all", res["figures"])] + list(res["per_form"].items()):
        print(
            f"bench gap_blind[{name}]: single right {_p(f['single_right'])} (named first "
            f"{_p(f['single_named_first_right'])}), null false alarms {_p(f['null_false_alarms'])}, "
            f"decoys unexplained {_p(f['decoys_unexplained'])}, pairs right {_p(f['pairs_right'])}, "
            f">=80% shrink only when right {_p(f['shrink_ge_80_only_when_right'])} (on right singles "
            f"{_p(f['shrink_ge_80_when_single_right'])})  counts {f['counts']}"
        )
    print(f"bench gap_blind per departure: {res['per_departure_single']}")
    if old is not None:
        of = old["figures"]
        print(
            f"bench gap_validate_old (self-generated, same code): top-1 single {_p(of['top1_single'])}, "
            f"null false alarms {_p(of['false_alarms_null'])}, "
            f"outside unexplained {_p(of['unexplained_outside'])}, "
            f"two-effect {_p(of['top1_in_two'])}"
        )
    for bar, ok in res["bars"].items():
        print(f"bench gap_blind bar {bar}: {'met' if ok else 'NOT MET'}")
    print(f"bench gap_blind: {n} trials in {t_blind:.0f} s; old validation {t_old:.0f} s ({jobs} workers)")
    if out is not None:
        out.write_text(json.dumps({"blind": res, "old": old}, default=str, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
