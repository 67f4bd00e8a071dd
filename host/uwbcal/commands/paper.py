"""`uwbcal paper --out DIR [--json] [--quick]`: re-run the paper's experiments in simulation.

Writes the figures (PNG) and one table (table.md, headline.json) into DIR: every headline number
next to the paper's. --doc docs/PAPER.md also writes the table into the doc (numbers in docs are
generated, not typed; tests/unit/test_paper_doc.py fails when the doc and a fresh run differ).
--scenario S runs them with the effects of scenario S (e.g. one fitted by
`uwbcal gap --write-scenario`). With --json prints one object whose "headline" list holds rows
{"name", "value", "unit", "paper", "note"} (also "bars", "figures", "seconds"). --quick runs
smaller sessions (for tests); the full run takes seconds on two cores.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``paper`` command."""
    p = subparsers.add_parser("paper", help="re-run the paper's experiments in simulation",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="directory for figures and table")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--quick", action="store_true", help="small runs (tests); same experiments")
    p.add_argument("--seed", type=int, default=1, help="run seed (default 1)")
    p.add_argument("--no-plots", action="store_true", help="skip the figures")
    p.add_argument("--doc", type=Path, default=None, metavar="PAPER.md",
                   help="also write the table into this doc between its generated-table markers "
                        "(docs/PAPER.md; a test checks the doc against a fresh run)")
    p.add_argument("--scenario", default=None, metavar="S",
                   help="scenario file or example name whose effects replace the paper scenarios' "
                        "(e.g. one written by `uwbcal gap --write-scenario`); stations stay the paper's")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the experiments, write table.md / headline.json / figures, print table or JSON."""
    from uwbcal.commands.analyze import _finite
    from uwbcal.paper import run_paper, table_markdown

    def log(msg: str) -> None:
        if not args.json:
            print(f"  {msg} ...", file=sys.stderr, flush=True)

    from uwbcal.physics.scenario import load_scenario

    effects_from = load_scenario(args.scenario) if args.scenario is not None else None
    result = _finite(run_paper(args.out, quick=args.quick, seed=args.seed, plots=not args.no_plots, log=log,
                               effects_from=effects_from))
    out = {k: result[k] for k in ("headline", "bars", "figures", "seconds", "quick", "seed")}
    out["scenario"] = args.scenario
    (args.out / "headline.json").write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    (args.out / "details.json").write_text(json.dumps(result["details"]) + "\n", encoding="utf-8")
    table = table_markdown(result)
    (args.out / "table.md").write_text(table + "\n", encoding="utf-8")
    if args.doc is not None:
        from uwbcal.errors import UwbcalError
        from uwbcal.paper import update_doc

        try:
            update_doc(args.doc, result)
        except (ValueError, OSError) as exc:
            raise UwbcalError(f"--doc {args.doc}: {exc}") from None
    if args.json:
        print(json.dumps(out))
    else:
        print(table)
        print("bars: " + ", ".join(f"{k} {'met' if v else 'NOT MET'}" for k, v in result["bars"].items()))
        print(f"figures in {args.out} ({len(result['figures'])}); {result['seconds']:.1f} s")
    return 0
