"""Run every benchmark (tools/bench/bench_*.py) and print its figures.

Each benchmark is a script that prints lines ``bench <name>: <value> <unit> [(<context>)]``
and exits non-zero if it could not run. Benchmarks measure; tests never assert on time.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path


def main() -> int:
    here = Path(__file__).resolve().parent
    scripts = sorted(here.glob("bench_*.py"))
    if len(sys.argv) > 1:
        scripts = [s for s in scripts if any(a in s.name for a in sys.argv[1:])]
    failed = []
    for script in scripts:
        print(f"== {script.name}", flush=True)
        t0 = time.perf_counter()
        rc = subprocess.call([sys.executable, str(script)])
        print(f"   ({script.name} took {time.perf_counter() - t0:.1f} s, exit {rc})", flush=True)
        if rc != 0:
            failed.append(script.name)
    if failed:
        print("benchmarks that failed to run: " + ", ".join(failed))
        return 1
    print(f"{len(scripts)} benchmarks ran")
    return 0


if __name__ == "__main__":
    sys.exit(main())
