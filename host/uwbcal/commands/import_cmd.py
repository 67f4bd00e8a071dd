"""`uwbcal import asil RUN_DIR --out S.db`: convert a real recording into a session file.

Formats: ``asil`` (asil-lab/Uwb-clock-and-antenna-delay-dataset: two nodes taking turns,
one CSV per node (2 or 4 nodes) plus parameters.yaml; see :mod:`uwbcal.importers.asil` for the conversion
into P1/P2/P3 drift triplets of each transmitter as received by every other node).
"""

from __future__ import annotations

import argparse
import json
from typing import Any


def register(sub: Any) -> None:
    """Add the `import` subcommand."""
    p = sub.add_parser(
        "import",
        help="convert a real recording (asil, 2..N nodes) into a session file",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("format", choices=["asil"], help="source format")
    p.add_argument("run_dir", help="the run directory (node CSVs and parameters.yaml)")
    p.add_argument("--out", required=True, help="session file to write (.db)")
    p.add_argument(
        "--try",
        dest="try_name",
        default=None,
        help="which try of the run (file prefix before _ttyACMn), if there are several",
    )
    p.add_argument("--force", action="store_true", help="overwrite an existing session file")
    p.add_argument("--json", action="store_true", help="print the import summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Import, write, and print what was kept and what was lost."""
    from uwbcal.importers import asil

    imported = asil.load_run(args.run_dir, args.try_name)
    out = asil.write_session(imported, args.out, overwrite=args.force)
    summary = {
        "out": str(out),
        "records": imported.n_records,
        **{k: v for k, v in imported.stats.items() if k != "records"},
        "directions": imported.meta["directions"],
        "timestamps_unwrapped_at_source": imported.meta["timestamps"]["unwrapped_at_source"],
    }
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"imported {imported.n_records} triplet records into {out}")
    for d in imported.meta["directions"]:
        print(
            f"  {d['tx_station']} -> {d['rx_station']}: {d['messages_sent']} messages sent, "
            f"{d['messages_lost']} lost {d['lost_message_ids']}, {d['triplets_complete']} triplets, "
            f"{d['triplets_incomplete']} incomplete skipped"
        )
    ts = imported.meta["timestamps"]
    how = "unwrapped at source, up to " if ts["unwrapped_at_source"] else "up to "
    print(
        f"  timestamps stored as given ({how}{ts['max_over_2_40']:.2f} x 2**40); "
        "analyses take differences modulo 2**40"
    )
    return 0
