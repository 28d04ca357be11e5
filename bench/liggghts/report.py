#!/usr/bin/env python3
"""Build the results table from run.sh's scratch directory.

usage: report.py WORKDIR STEPS SEED  (prints markdown)

Per (N, ranks) it reads bench_N_P.log (LIGGGHTS log), time_N_P.txt (/usr/bin/time -v) and
load_N_P.txt (1-minute load average just before the run), and settle_N.log.
"""
import glob
import os
import re
import sys

work, steps, seed = sys.argv[1], int(sys.argv[2]), sys.argv[3]


def grab(pattern, text, nth=0, group=1):
    hits = re.findall(pattern, text, re.M)
    return hits[nth] if len(hits) > nth else None


rows = []
for log in glob.glob(os.path.join(work, "bench_*_*.log")):
    n, np_ = map(int, re.match(r".*bench_(\d+)_(\d+)\.log$", log).groups())
    text = open(log, errors="replace").read()
    loop = float(grab(r"^Loop time of (\S+)", text, 1))        # 2nd run = the timed one
    atoms = int(grab(r"^BENCH N (\d+)", text))
    cpp = float(grab(r"^BENCH N \d+ contacts_per_particle (\S+)", text))
    builds = int(grab(r"^Neighbor list builds = (\d+)", text, 1))
    neighs = float(grab(r"^Ave neighs/atom = (\S+)", text, 1))
    mem_mb = float(grab(r"^Memory usage per processor = (\S+)", text, 1))
    timing = open(os.path.join(work, f"time_{n}_{np_}.txt")).read()
    rss_kb = int(grab(r"Maximum resident set size \(kbytes\): (\d+)", timing))
    cpu = float(grab(r"User time \(seconds\): (\S+)", timing)) + float(
        grab(r"System time \(seconds\): (\S+)", timing))
    load_file = os.path.join(work, f"load_{n}_{np_}.txt")
    load = open(load_file).read().strip() if os.path.exists(load_file) else "?"
    settle = grab(r"^SETTLED step (\d+)", open(os.path.join(work, f"settle_{n}.log"),
                                                errors="replace").read())
    rows.append((n, np_, (
        f"| {atoms} | {np_} | {settle} | {loop:.2f} | {atoms * steps / loop / 1e6:.2f} | "
        f"{atoms * (steps + 20) / cpu / 1e6:.2f} | {cpp:.2f} | {neighs:.2f} | {builds} | "
        f"{mem_mb * 1024 * np_ / atoms:.2f} | {rss_kb / atoms:.2f} | {load} |")))

print("| N | MPI ranks | settling steps | loop time (s) | M particle-steps/s (wall) "
      "| M particle-steps per CPU-s | contacts/particle | neighbour pairs/particle (half list) "
      "| neighbour builds (timed) | LIGGGHTS memory KiB/particle | max RSS KiB/particle "
      "| load (1 min) before |")
print("|" + "---|" * 12)
for _, _, row in sorted(rows):
    print(row)
