#!/usr/bin/env python3
"""Run the README's main job as a newcomer would: every command of the block between
``<!-- newcomer:begin -->`` and ``<!-- newcomer:end -->``, in order, on simulated stations.

    tools/newcomer.py --short      # small parameters (make test): a minute or two
    tools/newcomer.py              # the README's own parameters (make demo-full)

``uwbcal sim ... &`` starts the simulated world in the background (its ports become $P1, $P2,
replacing the README's example assignment line); every other command runs with ``--json``
appended, must exit 0 and print JSON that parses (its last line). ``--z-m`` takes the Z the
preceding `range` printed, as the README says to. --short scales the sweep and the counts down
(--steps 61 -> 31 with --step-db 0.5 -> 1, --per-step 2000 -> 60, --count 2000 -> 100). The
working files go to a temporary directory (or --workdir). Prints one line per command and
exits non-zero at the first failure, naming it.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHORT = {"--steps": {"61": "31"}, "--step-db": {"0.5": "1"}, "--per-step": {"2000": "60"},
         "--count": {"2000": "100"}}


def readme_commands(readme: Path) -> list[str]:
    """The block's commands, continuation lines joined, comments dropped."""
    text = readme.read_text(encoding="utf-8")
    m = re.search(r"<!-- newcomer:begin -->\s*```sh\n(.*?)```\s*<!-- newcomer:end -->", text, re.S)
    if m is None:
        raise SystemExit(f"{readme}: no newcomer block")
    joined = re.sub(r"\\\n\s*", " ", m.group(1))
    out = []
    for line in joined.splitlines():
        cmd = re.sub(r"\s+#.*$", "", line).strip()
        if cmd and not cmd.startswith("#"):
            out.append(cmd)
    return out


def shorten(argv: list[str]) -> list[str]:
    out = list(argv)
    for i in range(len(out) - 1):
        table = SHORT.get(out[i])
        if table and out[i + 1] in table:
            out[i + 1] = table[out[i + 1]]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--short", action="store_true", help="small parameters (make test)")
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--uwbcal", default=str(REPO / ".venv" / "bin" / "uwbcal"))
    args = ap.parse_args()
    work = args.workdir or Path(tempfile.mkdtemp(prefix="uwbcal-newcomer-"))
    work.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, UWBCAL_SIM_DIR=str(work / "sims"))
    env.setdefault("UWBCAL_STATION", str(REPO / "build" / "native" / "uwbcal-station"))
    ports: dict[str, str] = {}
    z_m: float | None = None
    sim: subprocess.Popen[str] | None = None
    t0 = time.monotonic()
    try:
        for n, cmd in enumerate(readme_commands(REPO / "README.md"), 1):
            if re.match(r"^P1=\S+ P2=\S+$", cmd):
                print(f"[{n:2d}] {cmd}  ->  P1={ports['P1']} P2={ports['P2']}")
                continue
            argv = shlex.split(cmd)
            if argv[0] != "uwbcal":
                raise SystemExit(f"step {n}: not a uwbcal command: {cmd}")
            background = argv[-1] == "&"
            argv = [args.uwbcal, *[a for a in argv[1:] if a != "&"]]
            argv = [ports.get(a[1:], a) if a.startswith("$") else a for a in argv]
            if args.short:
                argv = shorten(argv)
            if "--z-m" in argv and z_m is not None:
                argv[argv.index("--z-m") + 1] = f"{z_m:+.4f}"
            if "--json" not in argv:
                argv.append("--json")
            shown = "uwbcal " + shlex.join(argv[1:])
            if background:
                sim = subprocess.Popen(argv, cwd=work, env=env, stdout=subprocess.PIPE, text=True,
                                       start_new_session=True)
                assert sim.stdout is not None
                first = sim.stdout.readline()
                doc = json.loads(first)
                ports = {f"P{s['id']}": s["port"] for s in doc["stations"]}
                print(f"[{n:2d}] {shown} &  ->  {ports}")
                continue
            t = time.monotonic()
            r = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, check=False)
            lines = r.stdout.strip().splitlines()
            try:
                doc = json.loads(lines[-1]) if lines else None
            except json.JSONDecodeError:
                doc = None
            if r.returncode != 0 or doc is None:
                js = "ok" if doc is not None else "missing"
                print(f"[{n:2d}] FAILED (exit {r.returncode}, JSON {js}): {shown}\n{r.stdout[-2000:]}\n"
                      f"{r.stderr[-2000:]}", file=sys.stderr)
                return 1
            if isinstance(doc, dict) and argv[1] == "range":
                paper = ((doc.get("analysis") or {}).get("methods") or {}).get("paper") or {}
                z_m = paper.get("z_m", z_m)
            warn = doc.get("warnings") if isinstance(doc, dict) else None
            print(f"[{n:2d}] {shown}  ({time.monotonic() - t:.1f} s, JSON ok"
                  + (f", {len(warn)} warnings" if warn else "") + ")")
    finally:
        if sim is not None:
            os.killpg(sim.pid, signal.SIGTERM)
            sim.wait(10)
    print(f"newcomer run: every README command passed in {time.monotonic() - t0:.0f} s (files in {work})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
