"""``python -m bench speed``: every design against one plain SDP, in one run (issue 29).

For the paper's example and random families of n states (r = 5 plant modes, m = 2 inputs, n_drop = 10: 50 loop
modes; the seed ``speed_bench`` picks for a stabilizable family), one row per size:

* plain: ``design(decay_rate=None)``, the one-SDP design (the unit of every ratio);
* auto (the default ``design(family, n_drop)``), ``"max"`` (the best certified rate, ``rate_tol`` 1e-3): CPU,
  ratio to plain, SDP solves (``res.solve_count``);
* cost, hinf and u_max designs (``objective="cost"``, ``"hinf"``, ``u_max=1``): CPU and ratio to plain, up to
  ``--perf-max-n`` (their lifted blocks are issue 29's other part);
* Clarabel and CVXOPT: one plain SDP through cvxpy's compiled problem (canonicalization excluded), up to
  ``--peer-max-n``; the ratio is theirs to ``design()``'s plain SDP;
* est./measured: :func:`solver.compiled.design_size`'s estimate of the whole request (``total_seconds``, the
  one the library's refusal and the service's job time limit use; constants fitted by
  ``python -m bench size``) divided by the measured CPU, for every path (1 = exact).

Each cell runs in a child process (``bench/child.py``) with a memory and a wall-clock cap; times are CPU
(``time.process_time``) after a warm-up design on the paper's example; a cell repeats its design while the runs
total under 1 s CPU and reports the median.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

from .child import fmt, run_child

SIZES = ("paper", 8, 12, 20, 30, 50)
QUICK = ("paper", 8)
WHAT = ("plain", "auto", "max", "cost", "hinf", "u_max", "clarabel", "cvxopt")
R, M, N_DROP = 5, 2, 10


def family(n):
    from solver import PlantFamily

    from .cases import random_family
    from .speed_bench import FEASIBLE_SEED

    if n == "paper":
        return PlantFamily.paper_example(0.1), 3
    return random_family(n, R, M, seed=FEASIBLE_SEED.get(n, 0), spread=0.02), N_DROP


def child(n, what: str) -> dict:
    """One cell: CPU seconds of ``what`` on row ``n``, the outcome, the solves and the estimate."""
    import warnings

    import numpy as np

    from solver import PlantFamily, design
    from solver.design import request_size

    fam, n_drop = family(n)
    design(PlantFamily.paper_example(0.1), 3)  # first-use costs (imports, BLAS handles, caches)
    out = {"n": n, "what": what}
    if what in ("clarabel", "cvxopt"):
        import cvxpy as cp

        from solver.methods import lmi
        from solver.network import ModeSet

        modes = ModeSet.from_family(fam, n_drop)
        _, active = modes.scheme_coef()
        compiled = lmi.build(modes.n_states, modes.n_inputs, modes.n_modes, modes.n_free_gains, active)
        for key, value in lmi.plant_values(modes).items():
            compiled.parameters[key].value = value
        name = cp.CLARABEL if what == "clarabel" else cp.CVXOPT
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            compiled.problem.get_problem_data(name)  # canonicalization (cached by cvxpy): not timed
            c0 = time.process_time()
            compiled.problem.solve(solver=name, warm_start=False)
            out["cpu"] = time.process_time() - c0
        out["outcome"] = compiled.problem.status
        return out
    kw = {"plain": {"decay_rate": None}, "auto": {}, "max": {"decay_rate": "max"},
          "cost": {"objective": "cost", "decay_rate": None}, "hinf": {"objective": "hinf", "decay_rate": None,
                                                                   "disturbance": np.ones((fam.n_states, 1))},
          "u_max": {"u_max": np.ones(fam.n_inputs), "decay_rate": None}}[what]
    cpus = []
    while not cpus or (sum(cpus) < 1.0 and len(cpus) < 50):  # small cells: the median of repeats (shared machine)
        c0 = time.process_time()
        res = design(fam, n_drop, **kw)
        cpus.append(time.process_time() - c0)
    out["cpu"] = statistics.median(cpus)
    out["outcome"] = res.outcome
    out["solves"] = res.solve_count
    size = request_size("lmi", fam, n_drop, decay_rate=kw.get("decay_rate", "auto"),
                        objective=kw.get("objective", "stability"), u_max=kw.get("u_max"),
                        disturbance=kw.get("disturbance"))
    out["estimate"] = size.total_seconds
    return out


def run_cell(n, what: str, cap: float, mem_gb: float) -> dict:
    return run_child("from bench.design_speed import child", f"child({n!r}, {what!r})", mem_gb, cap, note_chars=40)


def cell_text(c: dict) -> str:
    if "note" in c:
        return c["note"]
    return fmt(c["cpu"]) if "cpu" in c else "-"


def table(rows: list) -> str:
    head = ("| n | plain | auto (x plain, solves) | max (x plain, solves) | cost (x) | hinf (x) | u_max (x) "
            "| Clarabel (x plain) | CVXOPT (x plain) | est./measured plain, auto, max, cost, hinf, u_max |")
    lines = [head, "|---" * (head.count("|") - 1) + "|"]
    for row in rows:
        base = row["plain"].get("cpu")

        def rel(c, solves=False):
            if "cpu" not in c or not base:
                return cell_text(c)
            s = f"{fmt(c['cpu'])} ({c['cpu'] / base:.1f}x"
            if solves and c.get("solves") is not None:
                s += f", {c['solves']}"
            return s + ")" + ("" if c.get("outcome") in ("stabilized", "optimal", None) else f" {c['outcome']}")

        def peer(c):
            if "cpu" not in c or not base:
                return cell_text(c)
            return f"{fmt(c['cpu'])} ({c['cpu'] / base:.1f}x)"

        est = ", ".join(f"{row[w]['estimate'] / row[w]['cpu']:.2f}" if row[w].get("estimate") and row[w].get("cpu")
                        else "-" for w in ("plain", "auto", "max", "cost", "hinf", "u_max"))
        plain = row["plain"]
        plain_txt = cell_text(plain) + ("" if plain.get("outcome") in ("stabilized", None) else f" {plain['outcome']}")
        lines.append(f"| {row['n']} | {plain_txt} | {rel(row['auto'], True)} | {rel(row['max'], True)} "
                     f"| {rel(row['cost'])} | {rel(row['hinf'])} | {rel(row['u_max'])} | {peer(row['clarabel'])} "
                     f"| {peer(row['cvxopt'])} | {est} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m bench speed", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help=f"rows {QUICK} only")
    p.add_argument("--sizes", default=",".join(map(str, SIZES)), help="rows, e.g. paper,8,20")
    p.add_argument("--perf-max-n", type=int, default=12, help="largest n of the cost, hinf and u_max designs")
    p.add_argument("--peer-max-n", type=int, default=12, help="largest n run on Clarabel and CVXOPT")
    p.add_argument("--cap", type=float, default=600.0, help="wall-clock cap per cell, s")
    p.add_argument("--mem-limit", type=float, default=6.0, help="address-space cap per cell, GB")
    p.add_argument("--solvers", action="store_true",
                   help="the older table instead: design() vs the IPM alone vs Clarabel/CVXOPT (bench/speed_bench.py)")
    a, rest = p.parse_known_args(argv)
    if a.solvers:
        from . import speed_bench

        return speed_bench.main(rest + (["--quick"] if a.quick else []))
    if rest:
        p.error(f"unrecognized arguments: {' '.join(rest)}")
    sizes = QUICK if a.quick else tuple(x if x == "paper" else int(x) for x in a.sizes.split(",") if x)
    with open("/proc/loadavg") as fh:
        load = " ".join(fh.read().split()[:3])
    print(f"every design against one plain SDP: {os.cpu_count()} cpus, load average {load}; random families r={R} "
          f"m={M} n_drop={N_DROP}; CPU time of one design per cell", flush=True)
    t0 = time.perf_counter()
    rows = []
    for n in sizes:
        row = {"n": n}
        for what in WHAT:
            big = n != "paper"
            if what in ("cost", "hinf", "u_max") and big and n > a.perf_max_n:
                row[what] = {"note": "-"}
            elif what in ("clarabel", "cvxopt") and big and n > a.peer_max_n:
                row[what] = {"note": "-"}
            else:
                row[what] = run_cell(n, what, a.cap, a.mem_limit)
            c = row[what]
            print(f"  n={n} {what}: {cell_text(c)} {c.get('outcome', '')} solves={c.get('solves', '-')}", flush=True)
        rows.append(row)
    print()
    print(table(rows))
    worst = max((row[w]["cpu"] / row["plain"]["cpu"] for row in rows for w in ("auto", "max")
                 if row[w].get("cpu") and row["plain"].get("cpu")), default=float("nan"))
    print(f"\nlargest auto or max / plain: {worst:.1f} (target <= 2)")
    errors = [row[w]["estimate"] / row[w]["cpu"] for row in rows for w in WHAT
              if row[w].get("estimate") and row[w].get("cpu")]
    if errors:
        print(f"size estimate / measured over every path: {min(errors):.2f} .. {max(errors):.2f} "
              f"(worst factor {max(max(errors), 1 / min(errors)):.2f})")
    print(f"(total {time.perf_counter() - t0:.0f} s wall)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
