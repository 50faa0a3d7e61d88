"""``python -m bench startup``: how long ``import solver`` and the command line take to answer.

Every figure is measured in a fresh subprocess (nothing cached in this one): the wall time of an import, the
``-X importtime`` cumulative time of the top module, and for ``ncs-design design`` the time to its first line of
output, to the design's summary and to exit, next to the solve time it reports (``timings.total``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

IMPORTS = [
    ("import solver", "import solver"),
    ("from solver import PlantFamily, design, analyze, simulate",
     "from solver import PlantFamily, design, analyze, simulate"),
    ("import solver.plotting (matplotlib)", "import solver.plotting"),
    ("import cvxpy (loaded only by ccl, SCS/CLARABEL, switched fixed-gain)", "import cvxpy"),
    ("import numpy, scipy.linalg (the floor)", "import numpy, scipy.linalg"),
]


def _wall(code: str) -> tuple[float, float]:
    """Wall time and CPU time (user + system, what an idle core would take) of a fresh process running code."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _importtime(code: str) -> float:
    """Cumulative microseconds of the first top-level module ``-X importtime`` reports for ``code``."""
    out = subprocess.run([sys.executable, "-X", "importtime", "-c", code], check=True, capture_output=True,
                         text=True).stderr
    top = code.replace("from ", "").replace("import ", "").split()[0].split(".")[0].rstrip(",")
    total = 0
    for line in out.splitlines():
        parts = [p.strip() for p in line.split("|")]
        if len(parts) == 3 and parts[2] == top:
            total = int(parts[1])
    return total / 1e6


def _cli(plant: Path, n_drop: int, extra: list[str]) -> dict:
    """Times (s) of one in-process ``ncs-design design`` call: first line, summary, exit, and its solve."""
    exe = Path(sys.executable).with_name("ncs-design")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "app.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "res.json"
        start = time.perf_counter()
        proc = subprocess.Popen(cmd + ["design", str(plant), "--n-drop", str(n_drop), "-o", str(out), *extra],
                                stdout=subprocess.PIPE, text=True)
        first = summary = None
        for line in proc.stdout:
            now = time.perf_counter() - start
            first = now if first is None else first
            if line.startswith("design:") and summary is None:
                summary = now
        proc.wait()
        total = time.perf_counter() - start
        solve = json.loads(out.read_text())["timings"]["total"]
    return {"first": first, "summary": summary, "total": total, "solve": solve}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench startup", description=__doc__)
    p.add_argument("--repeats", type=int, default=5)
    a = p.parse_args(argv)
    load = os.getloadavg() if hasattr(os, "getloadavg") else ("?",)
    print(f"start-up, median of {a.repeats} fresh processes; python {sys.version.split()[0]}, {os.cpu_count()} cpus, "
          f"load average {', '.join(f'{x:.2f}' for x in load)}\n")
    print("| import | wall (s) | process CPU (s) | -X importtime (s) |\n|---|---|---|---|")
    for name, code in IMPORTS:
        runs = [_wall(code) for _ in range(a.repeats)]
        wall, cpu = statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)
        it = statistics.median(_importtime(code) for _ in range(a.repeats))
        print(f"| `{name}` | {wall:.2f} | {cpu:.2f} | {it:.2f} |")
    with tempfile.TemporaryDirectory() as tmp:
        plant = Path(tmp) / "motor.json"
        plant.write_text('{"kind": "dc_motor", "inertias": [0.03, 0.05], "sampling_period": 0.1}')
        print("\n| `ncs-design design motor.json --n-drop 3` | first line (s) | summary (s) | exit (s) | "
              "solve (s) | summary - solve (s) |\n|---|---|---|---|---|---|")
        for label, extra in (("default (`decay_rate` auto)", []), ("`--decay-rate none`", ["--decay-rate", "none"]),
                             ("`--method ccl`", ["--method", "ccl"])):
            runs = [_cli(plant, 3, extra) for _ in range(a.repeats)]
            med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
            print(f"| {label} | {med['first']:.2f} | {med['summary']:.2f} | {med['total']:.2f} | "
                  f"{med['solve']:.3f} | {med['summary'] - med['solve']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
