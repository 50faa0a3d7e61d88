"""``python -m bench speed``: ``design()`` against its own solver, and both against CVXOPT and Clarabel.

For the paper's example and every size n (random families, r = 5 plant modes, m = 2 inputs, n_drop = 10: 50 loop
modes) and two
families, one the lmi design stabilizes ("feasible") and one it proves infeasible or marginal
("infeasible"), one run prints:

* ``design()``: the whole call (balancing, the SDP, the certificate re-check or the proof), median CPU;
* IPM: :func:`solver.ipm.solve_lmi` alone on the same (unscaled) SDP, median CPU;
* ``design() / IPM``: the overhead of everything around the solver (issue target <= 1.5);
* Clarabel and CVXOPT: the same SDP through cvxpy's compiled problem (solver/methods/lmi.py), CPU of the
  re-solve (canonicalization excluded, as in a warm ``design(solver="CLARABEL")``), up to ``--peer-max-n``.

Every cell runs in its own child process with a wall-clock cap and an address-space cap, so the memory
column is that cell's own peak resident set above its start.  Times are CPU (``time.process_time``):
the machine is shared, wall times vary with the load, CPU time of a single-threaded solver does not
(much).  The growth exponent of the IPM and of ``design()`` is fitted on log CPU against log n for
n >= 12.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import numpy as np

from .child import fmt, rss_mb, run_child

SIZES = ("paper", 2, 4, 8, 12, 16, 20, 32, 50, 64)
QUICK = ("paper", 2, 8, 12)
KINDS = ("feasible", "infeasible")
#: Per size, the seed of the "feasible" family (spread 0.02): the first seed that ``design`` stabilizes.
FEASIBLE_SEED = {20: 1}
R, M, N_DROP = 5, 2, 10


def family(n, kind: str):
    """The family of a row: n = "paper" is the paper's example (h = 0.1 s, n_drop = 3; feasible only)."""
    from solver import PlantFamily

    from .cases import random_family

    if n == "paper":
        return PlantFamily.paper_example(0.1) if kind == "feasible" else None
    if kind == "feasible":
        return random_family(n, R, M, seed=FEASIBLE_SEED.get(n, 0), spread=0.02)
    return random_family(n, R, M, seed=0, spread=0.5)


def child(n: int, kind: str, what: str, budget: float) -> dict:
    """One cell: ``what`` in ("design", "ipm", "clarabel", "cvxopt"); repeats until ``budget`` CPU seconds."""
    import resource
    import warnings

    from solver import PlantFamily, design, ipm
    from solver.network import ModeSet

    fam = family(n, kind)
    n_drop = 3 if n == "paper" else N_DROP
    modes = ModeSet.from_family(fam, n_drop)
    coef, active = modes.scheme_coef()
    design(PlantFamily.paper_example(0.1), 3)  # first-use costs (imports, BLAS handles, caches)
    out = {"n": n, "kind": kind, "what": what, "cpu": [], "wall": []}
    if what in ("clarabel", "cvxopt"):
        import cvxpy as cp

        from solver.methods import lmi

        compiled = lmi.build(modes.n_states, modes.n_inputs, modes.n_modes, modes.n_free_gains, active)
        for key, value in lmi.plant_values(modes).items():
            compiled.parameters[key].value = value
        name = cp.CLARABEL if what == "clarabel" else cp.CVXOPT

        def once():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                compiled.problem.solve(solver=name, warm_start=False)
            out.update(t=float(compiled.value("t")), status=compiled.problem.status)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            compiled.problem.get_problem_data(name)  # canonicalization (cached by cvxpy): not timed
    elif what == "ipm":
        def once():
            sol = ipm.solve_lmi(modes.free, coef, active)
            out.update(t=float(sol.t), status=sol.status, iterations=sol.iterations)
    else:
        def once():
            res = design(fam, n_drop, decay_rate=None)  # one SDP: the plain stability design
            out.update(outcome=res.outcome, status=res.solver_status,
                       proof=None if res.certificate is None else res.certificate.kind)
    base = rss_mb()
    spent = 0.0
    while spent < budget or not out["cpu"]:
        t0, c0 = time.perf_counter(), time.process_time()
        once()
        out["cpu"].append(time.process_time() - c0)
        out["wall"].append(time.perf_counter() - t0)
        spent += out["cpu"][-1]
        if len(out["cpu"]) >= 50:
            break
    out["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - base
    return out


def run_cell(n: int, kind: str, what: str, budget: float, cap: float, mem_gb: float) -> dict:
    return run_child("from bench.speed_bench import child", f"child({n!r}, {kind!r}, {what!r}, {budget})", mem_gb,
                     cap, note_chars=80)


def cpu(cell: dict) -> float:
    return statistics.median(cell["cpu"]) if cell.get("cpu") else float("nan")


def text(cell: dict) -> str:
    return cell["note"] if "note" in cell else fmt(cpu(cell))


def ratio(a: float, b: float, digits: int = 2) -> str:
    return "-" if not (a == a and b == b and b > 0) else f"{a / b:.{digits}f}"


def measure(sizes, peers_max_n: int, budget: float, mem_gb: float, echo=print) -> list:
    rows = []
    for n in sizes:
        for kind in KINDS:
            if family(n, kind) is None:
                continue
            size = 2 if n == "paper" else n
            cells = {}
            for what in ("design", "ipm", "clarabel", "cvxopt"):
                if what in ("clarabel", "cvxopt") and size > peers_max_n:
                    cells[what] = {"note": "not run"}
                    continue
                cap = 60.0 + 60.0 * (size / 12.0) ** 3 if what in ("design", "ipm") else 120.0 + 20.0 * size
                t0 = time.perf_counter()
                cells[what] = run_cell(n, kind, what, budget, cap, mem_gb)
                print(f"  n={n} {kind} {what}: {text(cells[what])} ({time.perf_counter() - t0:.0f} s wall)",
                      file=sys.stderr, flush=True)
            rows.append({"n": n, "kind": kind, **cells})
    return rows


def table(rows) -> str:
    head = ("| n | family | outcome | `design()` CPU | IPM CPU | design / IPM | Clarabel CPU | CVXOPT CPU "
            "| CVXOPT / design | Clarabel / design | peak memory design / IPM |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        d, i, c, v = r["design"], r["ipm"], r["clarabel"], r["cvxopt"]
        outcome = d.get("outcome", "-") + (f" ({d['proof']})" if d.get("proof") in ("farkas", "uncontrollable")
                                           else "")
        mem = " / ".join(f"{max(x['peak_mb'], 0.0):.0f} MB" if "peak_mb" in x else "-" for x in (d, i))
        lines.append(f"| {r['n']} | {r['kind']} | {outcome} | {text(d)} | {text(i)} | {ratio(cpu(d), cpu(i))} "
                     f"| {text(c)} | {text(v)} | {ratio(cpu(v), cpu(d), 0)} | {ratio(cpu(c), cpu(d), 0)} | {mem} |")
    return "\n".join(lines)


def exponents(rows) -> list:
    out = []
    for what in ("ipm", "design"):
        for kind in KINDS:
            pts = [(r["n"], cpu(r[what])) for r in rows
                   if r["kind"] == kind and r["n"] != "paper" and r["n"] >= 12 and cpu(r[what]) > 0]
            if len(pts) >= 3:
                slope = float(np.polyfit(np.log([p[0] for p in pts]), np.log([p[1] for p in pts]), 1)[0])
                out.append(f"{what} CPU ~ n^{slope:.2f} ({kind}, n = {pts[0][0]}..{pts[-1][0]})")
    return out


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m bench speed", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help=f"n in {QUICK} only, one repeat, peers up to n = 8")
    p.add_argument("--sizes", default=",".join(map(str, SIZES)))
    p.add_argument("--peer-max-n", type=int, default=20, help="largest n run on Clarabel and CVXOPT")
    p.add_argument("--budget", type=float, default=2.0, help="CPU seconds of repeats per cell (at least one)")
    p.add_argument("--mem-limit", type=float, default=6.0, help="address-space cap per cell, GB")
    p.add_argument("--service", action="store_true",
                   help="then the service against its in-process floor, both databases (python -m bench service-floor)")
    a = p.parse_args(argv)
    sizes = QUICK if a.quick else tuple(x if x == "paper" else int(x) for x in a.sizes.split(",") if x)
    budget = 0.0 if a.quick else a.budget
    if a.quick:
        a.peer_max_n = min(a.peer_max_n, 8)
    with open("/proc/loadavg") as fh:
        load = " ".join(fh.read().split()[:3])
    print(f"design() vs its solver: {os.cpu_count()} cpus, load average {load} at start; random families "
          f"r={R} m={M} n_drop={N_DROP}; CPU times (medians)", flush=True)
    t0 = time.perf_counter()
    rows = measure(sizes, a.peer_max_n, budget, a.mem_limit)
    print()
    print(table(rows))
    print()
    worst = max((cpu(r["design"]) / cpu(r["ipm"]) for r in rows
                 if cpu(r["design"]) == cpu(r["design"]) and cpu(r["ipm"]) > 0), default=float("nan"))
    print(f"largest design / IPM: {worst:.2f} (target <= 1.5)")
    for line in exponents(rows):
        print(line)
    with open("/proc/loadavg") as fh:
        load = " ".join(fh.read().split()[:3])
    print(f"\n(total {time.perf_counter() - t0:.0f} s wall; load average {load} at the end)")
    if a.service:  # the same run goes on to the service (issue: design(), the IPM and the service in one run)
        from . import service_floor

        print(flush=True)
        return service_floor.main(["--seconds", "4"] if a.quick else [])
    return 0


if __name__ == "__main__":
    sys.exit(main())
