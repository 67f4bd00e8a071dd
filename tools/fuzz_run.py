"""Run the libFuzzer harness (tests/fuzz/fuzz_station.c) for a while and print its figures.

    python tools/fuzz_run.py --seconds 600 --build build/fuzz [--coverage]

Runs ``BUILD/fuzz_station`` on the corpus ``BUILD/corpus`` (grown across runs) seeded from
``BUILD/seed``, one process (the machine is shared), then prints runs, execs/s, corpus size
and findings. ``--coverage`` replays the corpus on ``BUILD/fuzz_station_cov`` and prints line
coverage per firmware file (llvm-profdata, llvm-cov). Exit 1 when the fuzzer found anything
(the input is in BUILD/findings/), 0 otherwise.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def fuzz(build: Path, seconds: int) -> int:
    corpus, findings = build / "corpus", build / "findings"
    corpus.mkdir(parents=True, exist_ok=True)
    findings.mkdir(parents=True, exist_ok=True)
    before = {p.name for p in findings.iterdir()}
    cmd = [str(build / "fuzz_station"), f"-max_total_time={seconds}", "-print_final_stats=1", "-timeout=10",
           "-rss_limit_mb=2048", "-max_len=2048", f"-artifact_prefix={findings}/", str(corpus),
           str(build / "seed")]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    wall = time.monotonic() - t0
    log = proc.stdout
    (build / "last_run.log").write_text(log)
    stats = dict(re.findall(r"^stat::(\w+):\s+(\d+)", log, re.M))
    runs = int(stats.get("number_of_executed_units", 0))
    rate = int(stats.get("average_exec_per_sec", 0))
    cov = re.findall(r"cov: (\d+) ft: (\d+)", log)
    new = sorted({p.name for p in findings.iterdir()} - before)
    n_corpus = sum(1 for _ in corpus.iterdir())
    print(f"fuzz: {runs} runs in {wall:.0f} s, {rate} execs/s, corpus {n_corpus} inputs, "
          f"edges {cov[-1][0] if cov else '?'} features {cov[-1][1] if cov else '?'}, "
          f"{len(new)} finding(s)" + (f": {', '.join(new)} in {findings}" if new else ""))
    if proc.returncode != 0 and not new:
        print(f"fuzz: the fuzzer exited with {proc.returncode}; log in {build / 'last_run.log'}")
        print("\n".join(log.splitlines()[-15:]))
        return 1
    return 1 if new else 0


def coverage(build: Path) -> None:
    tools = {t: shutil.which(t) for t in ("llvm-profdata", "llvm-cov")}
    if not all(tools.values()):
        print("fuzz: coverage skipped: llvm-profdata / llvm-cov not installed")
        return
    raw = build / "cov.profraw"
    prof = build / "cov.profdata"
    env = dict(os.environ, LLVM_PROFILE_FILE=str(raw))
    subprocess.run([str(build / "fuzz_station_cov"), "-runs=0", str(build / "corpus"), str(build / "seed")],
                   cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    subprocess.run([str(tools["llvm-profdata"]), "merge", "-sparse", str(raw), "-o", str(prof)], check=True)
    rep = subprocess.run([str(tools["llvm-cov"]), "report", str(build / "fuzz_station_cov"),
                          f"-instr-profile={prof}"], cwd=ROOT, stdout=subprocess.PIPE, text=True, check=True)
    print("fuzz: line coverage per file (corpus replayed on the coverage build):")
    for line in rep.stdout.splitlines():
        parts = line.split()
        if parts and parts[0].startswith("firmware/") and len(parts) >= 10:
            print(f"  {parts[0]:<40} {parts[9]:>8} of {parts[7]} lines")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=int, default=600)
    ap.add_argument("--build", type=Path, default=ROOT / "build" / "fuzz")
    ap.add_argument("--coverage", action="store_true")
    args = ap.parse_args()
    rc = fuzz(args.build, args.seconds)
    if args.coverage:
        coverage(args.build)
    return rc


if __name__ == "__main__":
    sys.exit(main())
