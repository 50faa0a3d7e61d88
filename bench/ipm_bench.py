"""``python -m bench ipm``: the structured IPM (solver/ipm/) beside Clarabel and CVXOPT on the same lmi SDPs.

Every (case, solver) cell runs in its own child process with a wall-clock cap
(a cell that runs out prints "> cap s") and an address-space cap, so a slow
peer cannot stall the table and the memory column is that solver's alone:
"peak memory" is the child's peak resident set minus its resident set just
before the first solve (imports and the problem data excluded).

Times are medians over repeats of one solve of the SDP ``max t, trace W = n,
[[W, (A_s W)^T], [A_s W, W]] - t I >= 0``:

* IPM: :func:`solver.ipm.solve_lmi` wall time, Python included (building the
  structure from ``free``/``coef`` too);
* Clarabel (cvxpy): wall time of re-solving the project's compiled DPP problem
  (solver/methods/lmi.py), the way ``design(method="lmi")`` calls it;
* Clarabel (direct): ``clarabel.DefaultSolver`` on the same conic data, its own solve time;
* CVXOPT: the same compiled problem solved with ``solver=CVXOPT``, cvxpy's reported solver time.

The growth grid (``--grid``) runs the IPM only, in this process, in CPU time (the solver's phase
timings too: its clock is ``time.process_time`` during the grid, since the machine is shared), and fits
``time per iteration ~ n^a`` (and r, n_drop) by least squares on logs.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import numpy as np

from .child import fmt, rss_mb, run_child

SOLVERS = ("ipm", "clarabel_cvxpy", "clarabel_direct", "cvxopt")
CASES = {
    "paper": ("paper example h=0.1", 2, 3, 1, 3),
    "n12": ("random n=12 r=5 m=2 seed 0", 12, 5, 2, 10),
    "n20": ("random n=20 r=5 m=2 seed 0", 20, 5, 2, 10),
}


def modes_for(case: str):
    from solver import PlantFamily
    from solver.network import ModeSet

    from .cases import random_family

    _, n, r, m, N = CASES[case]
    fam = PlantFamily.paper_example(0.1) if case == "paper" else random_family(n, r, m, seed=0, spread=0.1)
    return ModeSet.from_family(fam, N)


def child(case: str, solver: str, repeats: int, cap: float) -> dict:
    import resource
    import warnings

    import cvxpy as cp

    from solver import ipm
    from solver.methods import lmi

    modes = modes_for(case)
    coef, active = modes.scheme_coef()
    n, m, S, J = modes.n_states, modes.n_inputs, modes.n_modes, modes.n_free_gains
    out = {"case": case, "solver": solver, "times": [], "cpu": []}
    if solver == "ipm":
        ipm.solve_lmi(modes.free, coef, active)  # first-use costs (imports, BLAS handles)
        base = rss_mb()
        t_end = time.perf_counter() + cap
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            sol = ipm.solve_lmi(modes.free, coef, active)
            out["times"].append(time.perf_counter() - t0)
            out["cpu"].append(time.process_time() - c0)
            if time.perf_counter() > t_end:
                break
        out.update(t=sol.t, status=sol.status, iterations=sol.iterations, timings=sol.timings)
    else:
        compiled = lmi.build(n, m, S, J, active)
        values = lmi.plant_values(modes)
        for key, value in values.items():
            compiled.parameters[key].value = value
        prob = compiled.problem
        base = rss_mb()
        for _ in range(repeats):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if solver == "clarabel_cvxpy":
                    t0, c0 = time.perf_counter(), time.process_time()
                    prob.solve(solver=cp.CLARABEL, warm_start=False)
                    out["times"].append(time.perf_counter() - t0)
                    out["cpu"].append(time.process_time() - c0)
                    out.update(t=float(compiled.value("t")), status=prob.status,
                               iterations=prob.solver_stats.num_iters)
                elif solver == "cvxopt":
                    t0, c0 = time.perf_counter(), time.process_time()
                    prob.solve(solver=cp.CVXOPT, warm_start=False)
                    out["times"].append(time.perf_counter() - t0)
                    out["cpu"].append(time.process_time() - c0)
                    out.update(t=float(compiled.value("t")), status=prob.status,
                               iterations=prob.solver_stats.num_iters)
                else:
                    import clarabel
                    import scipy.sparse as sp
                    from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import dims_to_solver_cones

                    data, _, _ = prob.get_problem_data(cp.CLARABEL)
                    q, A, b = data["c"], data["A"], data["b"]
                    P = sp.csc_matrix((q.size, q.size))
                    settings = clarabel.DefaultSettings()
                    settings.verbose = False
                    solver_obj = clarabel.DefaultSolver(P, q, A.tocsc(), b, dims_to_solver_cones(data["dims"]), settings)
                    c0 = time.process_time()
                    res = solver_obj.solve()
                    out["times"].append(float(res.solve_time))
                    out["cpu"].append(time.process_time() - c0)
                    out.update(t=-float(res.obj_val), status=str(res.status), iterations=int(res.iterations))
    out["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - base
    return out


def run_cell(case: str, solver: str, repeats: int, cap: float, mem_gb: float) -> dict:
    out = run_child("from bench.ipm_bench import child", f"child({case!r}, {solver!r}, {repeats}, {cap})", mem_gb,
                    cap + 30)
    return {"case": case, "solver": solver, **out} if "note" in out else out


def cell_text(c: dict) -> str:
    """Median wall time, median process CPU time in brackets (the time on an idle core for a
    single-threaded solver; a multi-threaded one can show more CPU than wall), iterations."""
    if "note" in c:
        return c["note"]
    it = c.get("iterations")
    return (f"{fmt(statistics.median(c['times']))} [cpu {fmt(statistics.median(c['cpu']))}]"
            f"{f' ({it} it)' if it is not None else ''}")


def main_table(cases, repeats: dict, caps: dict, mem_gb: float, echo=print) -> list:
    rows = []
    for case in cases:
        cells = {}
        for solver in SOLVERS:
            t0 = time.perf_counter()
            # The peers take seconds to minutes on the large cases: one timed solve each there.
            reps = repeats.get(case, 3) if (solver == "ipm" or case == "paper") else 1
            cells[solver] = run_cell(case, solver, reps, caps[solver].get(case, 60.0), mem_gb)
            print(f"  measured {case}/{solver} in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        rows.append((case, cells))
    return rows


def table(rows) -> str:
    head = ("| case | shape (vars, blocks) | IPM | Clarabel via cvxpy | Clarabel direct | CVXOPT | CVXOPT / IPM "
            "| t* (IPM) | max abs t* diff | IPM assembly / factorization / line search / other per solve "
            "| peak memory IPM / Clarabel / CVXOPT |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for case, cells in rows:
        desc, n, r, m, N = CASES[case]
        J = N
        p = n * (n + 1) // 2 + J * m * n  # W (trace-eliminated) + Y + t
        ipm = cells["ipm"]
        ts = [c["t"] for c in cells.values() if "t" in c]
        diff = max(abs(x - ipm["t"]) for x in ts) if "t" in ipm else float("nan")
        ratio = "-"
        if "times" in cells["cvxopt"] and "times" in ipm:
            ratio = f"{statistics.median(cells['cvxopt']['times']) / statistics.median(ipm['times']):.0f}x"
        elif "note" in cells["cvxopt"] and "times" in ipm:
            ratio = f"> {float(cells['cvxopt']['note'].split()[1]) / statistics.median(ipm['times']):.0f}x" \
                if cells["cvxopt"]["note"].startswith(">") else "-"
        br = "-"
        if "timings" in ipm:
            tm = ipm["timings"]
            br = " / ".join(fmt(tm[k]) for k in ("assembly", "factorization", "line_search", "other"))
        mem = " / ".join(f"{cells[s]['peak_mb']:.0f} MB" if "peak_mb" in cells[s] else "-"
                         for s in ("ipm", "clarabel_cvxpy", "cvxopt"))
        lines.append(f"| {case} | n={n} r={r} m={m} N={N} ({p}, {r * N} of side {2 * n}) | {cell_text(ipm)} "
                     f"| {cell_text(cells['clarabel_cvxpy'])} | {cell_text(cells['clarabel_direct'])} "
                     f"| {cell_text(cells['cvxopt'])} | {ratio} | {ipm.get('t', float('nan')):.9g} | {diff:.1e} "
                     f"| {br} | {mem} |")
    return "\n".join(lines)


def targets(rows) -> list:
    out = []
    med = {case: statistics.median(c["ipm"]["times"]) for case, c in rows if "times" in c["ipm"]}
    lim = {"paper": 1e-3, "n12": 0.5, "n20": 3.0}
    for case, t in med.items():
        out.append(f"{'PASS' if t <= lim[case] else 'MISS'}  IPM {case}: {fmt(t)} (target <= {fmt(lim[case])})")
    for case, cells in rows:
        if case == "n20" and "times" in cells["ipm"]:
            cv = cells["cvxopt"]
            if "times" in cv:
                r = statistics.median(cv["times"]) / med[case]
                out.append(f"{'PASS' if r >= 20 else 'MISS'}  n20: CVXOPT / IPM = {r:.1f}x (target >= 20x)")
    return out


# ----------------------------------------------------------------------------- growth grid
GRID = ([(n, 3, 5) for n in (2, 4, 8, 12, 16, 24, 32, 48, 64)]
        + [(8, r, 5) for r in (1, 2, 4, 8)]
        + [(8, 2, N) for N in (1, 2, 4, 8, 16)])


def run_grid(repeats: int = 3, m: int = 2) -> list:
    from solver import ipm
    from solver.network import ModeSet

    from .cases import random_family

    rows = []
    clock = time.perf_counter
    time.perf_counter = time.process_time  # the solver's phase timings in CPU seconds (restored below)
    try:
        for n, r, N in GRID:
            rows.append(_grid_cell(ipm, ModeSet, random_family, n, r, N, m, repeats))
    finally:
        time.perf_counter = clock
    return rows


def _grid_cell(ipm, ModeSet, random_family, n, r, N, m, repeats):
    modes = ModeSet.from_family(random_family(n, r, m, seed=1, spread=0.1), N)
    coef, active = modes.scheme_coef()
    runs = []
    for _ in range(repeats if n < 48 else 1):
        t0 = time.process_time()
        sol = ipm.solve_lmi(modes.free, coef, active)
        runs.append((time.process_time() - t0, sol))
    wall, sol = sorted(runs, key=lambda x: x[0])[len(runs) // 2]
    return {"n": n, "r": r, "N": N, "p": n * (n + 1) // 2 + N * m * n, "wall": wall, "it": sol.iterations,
            "status": sol.status, **{k: sol.timings[k] for k in ("assembly", "factorization", "line_search",
                                                                 "other")}}


def _fit(rows, key, fixed):
    sel = [r for r in rows if all(r[k] == v for k, v in fixed.items())]
    x = np.log([r[key] for r in sel])
    y = np.log([r["wall"] / r["it"] for r in sel])
    return float(np.polyfit(x, y, 1)[0]) if len(sel) >= 3 else float("nan")


def grid_table(rows) -> str:
    lines = ["| n | r | n_drop | variables | status | iterations | CPU | per iteration | assembly | factorization "
             "| line search | other |", "|" + "---|" * 12]
    for r in rows:
        lines.append(f"| {r['n']} | {r['r']} | {r['N']} | {r['p']} | {r['status']} | {r['it']} | {fmt(r['wall'])} "
                     f"| {fmt(r['wall'] / r['it'])} | {fmt(r['assembly'])} | {fmt(r['factorization'])} "
                     f"| {fmt(r['line_search'])} | {fmt(r['other'])} |")
    lines.append("")
    large = [r for r in rows if r["n"] >= 16]
    lines.append(f"fitted exponents of CPU per iteration: n^{_fit(rows, 'n', {'r': 3, 'N': 5}):.2f} (r=3, n_drop=5; "
                 f"n >= 16: n^{_fit(large, 'n', {'r': 3, 'N': 5}):.2f}), "
                 f"r^{_fit(rows, 'r', {'n': 8, 'N': 5}):.2f} (n=8, n_drop=5), "
                 f"n_drop^{_fit(rows, 'N', {'n': 8, 'r': 2}):.2f} (n=8, r=2)")
    return "\n".join(lines)


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m bench ipm")
    p.add_argument("--cases", default="paper,n12,n20")
    p.add_argument("--clarabel-cap", type=float, default=120.0, help="seconds per Clarabel cell at n=12/20")
    p.add_argument("--cvxopt-cap", type=float, default=300.0)
    p.add_argument("--mem-limit", type=float, default=6.0)
    p.add_argument("--grid", action="store_true")
    p.add_argument("--no-table", action="store_true")
    a = p.parse_args(argv)
    with open("/proc/loadavg") as fh:
        load = " ".join(fh.read().split()[:3])
    print(f"IPM benchmark: {os.cpu_count()} cpus, load average {load} at start", flush=True)
    t0 = time.perf_counter()
    if not a.no_table:
        cases = [c for c in a.cases.split(",") if c]
        repeats = {"paper": 300, "n12": 5, "n20": 3}
        big = {"paper": 60.0}
        caps = {"ipm": {"paper": 60.0, "n12": 120.0, "n20": 300.0},
                "clarabel_cvxpy": dict(big, n12=a.clarabel_cap, n20=a.clarabel_cap),
                "clarabel_direct": dict(big, n12=a.clarabel_cap, n20=a.clarabel_cap),
                "cvxopt": dict(big, n12=a.cvxopt_cap, n20=a.cvxopt_cap)}
        rows = main_table(cases, repeats, caps, a.mem_limit)
        print()
        print("Median wall time of one solve [median process CPU time] (iterations); CVXOPT / IPM = wall-time "
              "ratio from the same run; t* diff = largest |t*(solver) - t*(IPM)|:")
        print()
        print(table(rows))
        print()
        for line in targets(rows):
            print(line)
    if a.grid:
        print()
        print("Growth of the IPM (random families, m = 2, lmi):")
        print()
        print(grid_table(run_grid()))
    with open("/proc/loadavg") as fh:
        load = " ".join(fh.read().split()[:3])
    print(f"\n(total {time.perf_counter() - t0:.0f} s; load average {load} at the end)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
