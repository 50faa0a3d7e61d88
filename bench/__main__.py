"""``python -m bench``: print the solver benchmark tables.

``python -m bench service [options]`` runs the service benchmark instead
(``bench/service_bench.py``: the real server over HTTP, SQLite and PostgreSQL;
``python -m bench service --help``); ``python -m bench service-floor`` drives it with wrk at 1, 4, 16, 64
clients against the in-process floor (``bench/service_floor.py``).  ``python -m bench ipm [--grid]`` compares the
structured interior-point solver with Clarabel and CVXOPT (``bench/ipm_bench.py``);
``python -m bench ipm-check [--count N]`` cross-checks it against Clarabel (``bench/ipm_check.py``);
``python -m bench ccl`` times the ccl design on the IPM vs Clarabel (``bench/ccl_bench.py``) and
``python -m bench ccl-check [--count N]`` cross-checks the two ccl paths (``bench/ccl_check.py``);
``python -m bench methods`` measures which method when (``bench/methods_bench.py``);
``python -m bench performance`` prints the cost/H-infinity brackets on the paper's motor (``bench/performance_bench.py``);
``python -m bench performance --speed`` times each objective on the IPM, Clarabel and CVXOPT;
``python -m bench perf-check [--count N]`` cross-checks the performance designs on the IPM against Clarabel
(``bench/perf_check.py``); ``python -m bench brackets [--count N]`` prints how far the cost/H-infinity brackets
close before/after the prefix search (``bench/brackets_check.py``).
``python -m bench speed [--quick] [--sizes paper,8,20]`` prints every design (plain, auto, max, cost, hinf, u_max)
against one plain SDP, Clarabel and CVXOPT, with the solves and the time estimate's error (``bench/design_speed.py``);
``python -m bench speed --solvers [--quick] [--service]`` prints ``design()`` beside the IPM alone, Clarabel and CVXOPT
for n = 2..64, feasible and infeasible families (``bench/speed_bench.py``).
``python -m bench size [--no-fit]`` fits the size estimate (``design_size``) to measured designs on every path and
prints estimate / measured per path and size (``bench/size_calibration.py``).
``python -m bench startup`` times ``import solver`` and the command line's first output (``bench/startup_bench.py``).

Options::

    --quick            paper example only, few repeats (well under a minute)
    --repeats N        warm repeats per cell (default 20; the paper-example lmi uses --paper-repeats)
    --paper-repeats N  warm repeats of the paper-example lmi design (default 200, ~3 ms each)
    --hand-repeats N   hand-written baseline runs per cell (default 10)
    --cold-repeats N   cold designs per cell, each after problem_cache.clear() (default 5)
    --ccl-limit S      per-case time budget of ccl, seconds (default 120)
    --lmi-limit S      per-case time budget of lmi, seconds (default 120)
    --cases a,b        subset of paper,n4,n8,n20
    --mem-limit GB     address-space cap of each measuring process (default 6)
    --grid             also run the growth grid (lmi over n, r, n_drop)
    --grid-max-rows R  skip grid cells with more LMI rows than R (default 256)
    --no-table         only the grid
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time


def _header() -> str:
    import clarabel
    import cvxpy
    import numpy

    import solver

    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "solver"], capture_output=True, text=True).stdout.strip()
    except OSError:
        rev, dirty = "?", ""
    load = os.getloadavg() if hasattr(os, "getloadavg") else ("?",)
    return (f"solver benchmark: commit {rev}{' (solver/ modified)' if dirty else ''}, python {platform.python_version()}, "
            f"cvxpy {cvxpy.__version__}, clarabel {clarabel.__version__}, numpy {numpy.__version__}, "
            f"solver from {os.path.dirname(solver.__file__)}, {os.cpu_count()} cpus, load average {', '.join(f'{x:.2f}' for x in load)}")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "service":
        from . import service_bench

        return service_bench.main(argv[1:])
    if argv and argv[0] == "service-floor":
        from . import service_floor

        return service_floor.main(argv[1:])
    if argv and argv[0] == "ipm":
        from . import ipm_bench

        return ipm_bench.main(argv[1:])
    if argv and argv[0] == "network":
        from . import network_bench

        return network_bench.main(argv[1:])
    if argv and argv[0] == "ccl":
        from . import ccl_bench

        return ccl_bench.main(argv[1:])
    if argv and argv[0] == "ccl-check":
        from . import ccl_check

        return ccl_check.main(argv[1:])
    if argv and argv[0] == "methods":
        from . import methods_bench

        return methods_bench.main(argv[1:])
    if argv and argv[0] == "performance":
        from . import performance_bench

        return performance_bench.main(argv[1:])
    if argv and argv[0] == "speed":
        from . import design_speed

        return design_speed.main(argv[1:])
    if argv and argv[0] == "size":
        from . import size_calibration

        return size_calibration.main(argv[1:])
    if argv and argv[0] == "startup":
        from . import startup_bench

        return startup_bench.main(argv[1:])
    if argv and argv[0] == "perf-check":
        from . import perf_check
        return perf_check.main(argv[1:])
    if argv and argv[0] == "brackets":
        from . import brackets_check

        return brackets_check.main(argv[1:])
    if argv and argv[0] == "ipm-check":
        from . import ipm_check

        return ipm_check.main(argv[1:])
    p = argparse.ArgumentParser(prog="python -m bench", description="Solver benchmark tables.")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--paper-repeats", type=int, default=200)
    p.add_argument("--hand-repeats", type=int, default=10)
    p.add_argument("--cold-repeats", type=int, default=5)
    p.add_argument("--ccl-limit", type=float, default=120.0)
    p.add_argument("--lmi-limit", type=float, default=120.0)
    p.add_argument("--mem-limit", type=float, default=6.0)
    p.add_argument("--cases", default="paper,n4,n8,n20")
    p.add_argument("--grid", action="store_true")
    p.add_argument("--grid-max-rows", type=int, default=256)
    p.add_argument("--no-table", action="store_true")
    a = p.parse_args(argv)

    from . import solver_bench
    from .cases import CASES

    cases = [c.strip() for c in a.cases.split(",") if c.strip()]
    for c in cases:
        if c not in CASES:
            p.error(f"unknown case {c!r}; choose from {', '.join(CASES)}")
    if a.quick:
        cases = ["paper"]
        a.repeats, a.paper_repeats, a.hand_repeats, a.cold_repeats = 10, 100, 5, 3
        a.ccl_limit = min(a.ccl_limit, 20.0)

    print(_header(), flush=True)
    t0 = time.perf_counter()
    if not a.no_table:
        sums = solver_bench.main_table(cases, a.repeats, a.hand_repeats, a.cold_repeats, a.ccl_limit,
                                       a.lmi_limit, a.paper_repeats, a.mem_limit)
        print()
        print("Per method and shape (times are medians; Clarabel = sum of Clarabel's own solve times in one design;")
        print("cold = first design after problem_cache.clear(), incl. building and canonicalizing the cvxpy problem;")
        print("hand-written rebuild = plain cvxpy code that builds a new cp.Problem for every solve)")
        print()
        print(solver_bench.table(sums))
        print()
        for line in solver_bench.targets(sums):
            print(line)
    if a.grid:
        from .grid import grid_table, run_grid

        print()
        print(f"Growth of lmi (random families, m=1; cells above {a.grid_max_rows} LMI rows skipped):")
        print()
        print(grid_table(run_grid(repeats=3 if a.quick else 5, max_rows=a.grid_max_rows)))
    print(f"\n(total {time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
