"""``python -m bench size``: fit the size estimate's constants to measured designs (issue 29, item 4).

:func:`solver.compiled.design_size` estimates the CPU time and memory of a whole design request from its
dimensions alone; the library refuses (:func:`solver.design`, :func:`solver.analyze`) and the service limits
(``NCS_JOB_TIME_LIMIT``, ``NCS_WORKER_MEMORY_MB``) with it.  This script measures designs on every path (plain, a
given rate, ``"auto"``, ``"max"``, cost, H-infinity, input limits, switched, ccl, a network; n = 2 to 50), each in a
child process of its own at one BLAS thread (CPU time by ``time.process_time``, the peak resident set above the
interpreter's by ``getrusage``, and what the design did: every IPM run's Newton steps, groups, Schur size and CPU,
the bracket's lower-bound search's CPU), then fits in three least-squares problems on log CPU time
(docs/design.md §3.6):

1. one step's constants (:data:`~solver.compiled.ESTIMATE_ASSEMBLY_FLOPS_PER_SECOND`,
   :data:`~solver.compiled.ESTIMATE_BLOCK_FLOPS_PER_SIDE`, :data:`~solver.compiled.ESTIMATE_SECONDS_PER_BLOCK`,
   :data:`~solver.compiled.ESTIMATE_SECONDS_PER_STEP`) on the IPM's CPU per measured Newton step;
2. the lower-bound search's rate and fixed part per kind on its own CPU (cost, hinf);
3. each path's :data:`~solver.compiled.ESTIMATE_PATH_ITERATIONS` (``"rate"`` follows ``"plain"``),
   :data:`~solver.compiled.ESTIMATE_SECONDS_PER_MODE` and :data:`~solver.compiled.ESTIMATE_SECONDS_FIXED` on the
   whole request's CPU,

and prints, per path and size, the estimate, the measured CPU and their ratio (and the Newton steps and the search
estimated / measured, the memory against the resident growth), with the constants to put in solver/compiled.py.
``--save FILE`` keeps the measured rows, ``--load FILE`` refits to them without measuring (bench/size_rows.json:
the rows behind today's constants); ``--no-fit`` prints today's table only.  Designs that fail or hit ``--cap``
are listed but not fitted.  Measuring runs about 5 minutes of CPU (15 minutes wall on the shared machine).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time

from .child import fmt, run_child

#: (label, path, family, n_drop, keywords of design()).  Families: "paper" (n = 2, r = 3, m = 1), "pend" (the
#: CTMS pendulum with two pole lengths: n = 4, r = 2, m = 1), "rN" (random, n = N, r = 5, m = 2, as bench speed).
CASES = [
    ("plain", "paper", 3, {"decay_rate": None}),
    ("plain", "pend", 10, {"decay_rate": None}),
    ("plain", "pend", 50, {"decay_rate": None}),
    ("plain", "pend", 100, {"decay_rate": None}),
    ("plain", "r8", 10, {"decay_rate": None}),
    ("plain", "r12", 10, {"decay_rate": None}),
    ("plain", "r20", 10, {"decay_rate": None}),
    ("rate", "paper", 3, {"decay_rate": 0.9}),
    ("auto", "paper", 3, {}),
    ("auto", "pend", 10, {}),
    ("auto", "pend", 50, {}),
    ("auto", "r8", 10, {}),
    ("auto", "r12", 10, {}),
    ("max", "paper", 3, {"decay_rate": "max"}),
    ("max", "pend", 20, {"decay_rate": "max"}),
    ("max", "r8", 10, {"decay_rate": "max"}),
    ("plain", "r30", 10, {"decay_rate": None}),
    ("plain", "r50", 10, {"decay_rate": None}),
    ("auto", "r20", 10, {}),
    ("auto", "r30", 10, {}),
    ("auto", "r50", 10, {}),
    ("max", "r20", 10, {"decay_rate": "max"}),
    ("max", "r30", 10, {"decay_rate": "max"}),
    ("max", "r50", 10, {"decay_rate": "max"}),
    ("cost", "paper", 3, {"objective": "cost"}),
    ("cost", "pend", 5, {"objective": "cost"}),
    ("cost", "r8", 10, {"objective": "cost"}),
    ("cost", "r12", 10, {"objective": "cost"}),
    ("cost", "r20", 10, {"objective": "cost"}),
    ("cost", "r30", 10, {"objective": "cost"}),
    ("hinf", "paper", 3, {"objective": "hinf", "disturbance": "ones"}),
    ("hinf", "r8", 10, {"objective": "hinf", "disturbance": "ones"}),
    ("hinf", "r12", 10, {"objective": "hinf", "disturbance": "ones"}),
    ("hinf", "r20", 10, {"objective": "hinf", "disturbance": "ones"}),
    ("hinf", "r30", 10, {"objective": "hinf", "disturbance": "ones"}),
    ("u_max", "paper", 3, {"u_max": "ones", "decay_rate": None}),
    ("u_max", "r8", 10, {"u_max": "ones", "decay_rate": None}),
    ("u_max", "r12", 10, {"u_max": "ones", "decay_rate": None}),
    ("u_max", "r20", 10, {"u_max": "ones", "decay_rate": None}),
    ("u_max", "r30", 10, {"u_max": "ones", "decay_rate": None}),
    ("switched", "paper", 3, {"method": "switched", "decay_rate": None}),
    ("switched", "pend", 4, {"method": "switched", "decay_rate": None}),
    ("ccl", "paper", 3, {"method": "ccl"}),
    ("network", "paper", 3, {"network": "delays", "decay_rate": None}),
    ("network", "pend", 4, {"network": "weakly_hard", "decay_rate": None}),
]


def family(name: str):
    from solver import PlantFamily

    if name == "paper":
        return PlantFamily.paper_example(0.1)
    if name == "pend":
        sys.path.insert(0, ".")
        from tests.solver.textbook import pendulum

        return pendulum()
    from .cases import random_family
    from .speed_bench import FEASIBLE_SEED

    n = int(name[1:])
    return random_family(n, 5, 2, seed=FEASIBLE_SEED.get(n, 0), spread=0.02)


def request(fam_name: str, n_drop: int, kw: dict):
    """(family, design keywords) of a case, its placeholders made arrays."""
    import numpy as np

    from solver import Network

    fam = family(fam_name)
    kw = dict(kw)
    if kw.get("disturbance") == "ones":
        kw["disturbance"] = np.ones((fam.n_states, 1))
    if kw.get("u_max") == "ones":
        kw["u_max"] = np.ones(fam.n_inputs)
    if kw.get("network") == "delays":
        kw["network"] = Network.delays(1, n_drop)
    elif kw.get("network") == "weakly_hard":
        kw["network"] = Network.weakly_hard(2, 5, n_drop)
    return fam, kw


def child(fam_name: str, n_drop: int, kw: dict, cap: float, log: dict | None = None) -> dict:
    """One measured design in this (fresh) process: CPU, outcome, solves, peak RSS above the warmed-up one."""
    import resource

    from solver import PlantFamily, design

    design(PlantFamily.paper_example(0.1), 3)  # first-use costs (imports, BLAS handles, caches)
    fam, kw = request(fam_name, n_drop, kw)
    if log is not None:  # the warm-up's records are not this design's
        log["ipm"].clear()
        log["lower_bound"], log["sdp"] = 0.0, [0, 0.0]
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0
    c0 = time.process_time()
    try:
        res = design(fam, n_drop, time_limit=cap, **kw)
        out = {"outcome": res.outcome, "solves": res.solve_count}
        if "time limit" in (res.message or ""):
            out["outcome"] = "time_limit"
    except Exception as err:  # noqa: BLE001 (reported in the table, not fitted)
        out = {"outcome": type(err).__name__}
    out["cpu"] = time.process_time() - c0
    out["rss"] = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0 - base, 0.0)
    if log is not None:
        out["detail"] = log
    return out


def _instrument() -> dict:
    """Wrap the IPM core, the lower-bound search and the cvxpy solves to record what a design does: per IPM run
    its iterations, groups (blocks, side), Schur size and CPU; the CPU of the bracket's lower-bound search; the
    count and CPU of conic solves through cvxpy.  The record is what the estimate's shape is checked against."""
    from solver import brackets
    from solver.ipm import algorithm, rate_path

    log = {"ipm": [], "lower_bound": 0.0, "sdp": [0, 0.0]}
    core = algorithm._ipm_core

    def timed_core(C, b, *args, **kw):
        c0 = time.process_time()
        out = core(C, b, *args, **kw)
        log["ipm"].append([int(out.iterations), [[int(c.shape[0]), int(c.shape[1])] for c in C], int(len(b)),
                           time.process_time() - c0])
        return out

    algorithm._ipm_core = rate_path._ipm_core = timed_core
    lower = brackets.lower_bound

    def timed_lower(*args, **kw):
        c0 = time.process_time()
        try:
            return lower(*args, **kw)
        finally:
            log["lower_bound"] += time.process_time() - c0

    brackets.lower_bound = timed_lower
    solve = brackets.solve_sdp

    def timed_solve(*args, **kw):
        c0 = time.process_time()
        try:
            return solve(*args, **kw)
        finally:
            log["sdp"][0] += 1
            log["sdp"][1] += time.process_time() - c0

    brackets.solve_sdp = timed_solve
    return log


def child_detail(fam_name: str, n_drop: int, kw: dict, cap: float) -> dict:
    """:func:`child` with the record of :func:`_instrument` (key ``detail``)."""
    log = _instrument()
    out = child(fam_name, n_drop, kw, cap, log)
    return out


def size_of(fam_name: str, n_drop: int, kw: dict):
    from solver.design import request_size

    fam, kw = request(fam_name, n_drop, kw)
    return request_size(kw.pop("method", "lmi"), fam, n_drop, decay_rate=kw.get("decay_rate", "auto"),
                        objective=kw.get("objective", "stability"), u_max=kw.get("u_max"),
                        disturbance=kw.get("disturbance"), network=kw.get("network"))


#: The scalar constants of the fit (solver/compiled.py); the per-path and per-kind ones are dicts (DICTS).
NAMES = ("ESTIMATE_FLOPS_PER_SECOND", "ESTIMATE_ASSEMBLY_FLOPS_PER_SECOND", "ESTIMATE_BLOCK_FLOPS_PER_SIDE",
         "ESTIMATE_SECONDS_PER_BLOCK",
         "ESTIMATE_SECONDS_PER_STEP", "ESTIMATE_SECONDS_PER_MODE", "ESTIMATE_SECONDS_FIXED")
DICTS = ("ESTIMATE_PATH_ITERATIONS", "ESTIMATE_SEARCH_FLOPS_PER_SECOND", "ESTIMATE_SEARCH_SECONDS")
#: Paths whose IPM runs are the model's blocks (the per-step constants are fitted on their measured steps).
STEP_PATHS = ("plain", "rate", "auto", "max", "cost", "hinf", "u_max")


def constants() -> dict:
    from solver import compiled

    return {**{k: getattr(compiled, k) for k in NAMES}, **{k: dict(getattr(compiled, k)) for k in DICTS}}


def apply(c: dict) -> None:
    from solver import compiled

    for k in NAMES:
        setattr(compiled, k, c[k])
    for k in DICTS:
        getattr(compiled, k).clear()
        getattr(compiled, k).update(c[k])


def _steps(r: dict) -> tuple[int, float]:
    """(Newton steps, their CPU) of a measured row's IPM runs."""
    runs = r.get("detail", {}).get("ipm", [])
    return sum(x[0] for x in runs), sum(x[3] for x in runs)


def _least_squares(residuals, size: int):
    import numpy as np
    from scipy.optimize import least_squares

    # a weak pull to the starting constants keeps the directions the data do not see where they were
    return least_squares(lambda x: np.concatenate([residuals(x), 0.05 * np.asarray(x)]), np.zeros(size)).x


def fit(rows: list, start: dict) -> dict:
    """The constants, fitted in three least-squares problems on log CPU time (each on what it predicts):

    1. the per-step constants (the flop rates, per block) on the IPM's measured CPU per measured Newton step;
    2. per kind, the lower-bound search's flop rate and fixed part on its measured CPU (cost, hinf);
    3. each path's Newton steps per solve, the per-mode and fixed seconds on the whole request's CPU.
    """
    import copy

    c = copy.deepcopy(start)
    good = [r for r in rows if r.get("fit")]
    stepped = [r for r in good if r["path"] in STEP_PATHS and _steps(r)[0] > 0 and _steps(r)[1] > 0]

    def step_constants(x):
        out = copy.deepcopy(c)
        # the Schur complement's Cholesky factor runs at LAPACK's rate (measured: dpotrf, one thread, p = 610 to
        # 2275: 15-24 Gflop/s; ESTIMATE_FLOPS_PER_SECOND is set to it, not fitted: the steps alone cannot tell it
        # from the pieces' rate); x[0] is free for the pieces' rate's second part, unused
        out["ESTIMATE_ASSEMBLY_FLOPS_PER_SECOND"] = c["ESTIMATE_ASSEMBLY_FLOPS_PER_SECOND"] * math.exp(x[1])
        out["ESTIMATE_SECONDS_PER_BLOCK"] = c["ESTIMATE_SECONDS_PER_BLOCK"] * math.exp(x[2])
        out["ESTIMATE_SECONDS_PER_STEP"] = c["ESTIMATE_SECONDS_PER_STEP"] * math.exp(x[3])
        out["ESTIMATE_BLOCK_FLOPS_PER_SIDE"] = c["ESTIMATE_BLOCK_FLOPS_PER_SIDE"] * math.exp(x[4])
        return out

    def step_residuals(x):
        apply(step_constants(x))
        return [math.log(size_of(*r["case"]).step_seconds * _steps(r)[0] / _steps(r)[1]) for r in stepped]

    if stepped:
        c = step_constants(_least_squares(step_residuals, 5))
    for kind in ("cost", "hinf"):
        searched = [r for r in good if r["path"] == kind and r.get("detail", {}).get("lower_bound", 0) > 0]
        if not searched:
            continue

        def search_constants(x, kind=kind):
            out = copy.deepcopy(c)
            out["ESTIMATE_SEARCH_FLOPS_PER_SECOND"][kind] = c["ESTIMATE_SEARCH_FLOPS_PER_SECOND"][kind] * math.exp(x[0])
            out["ESTIMATE_SEARCH_SECONDS"][kind] = c["ESTIMATE_SEARCH_SECONDS"][kind] * math.exp(x[1])
            return out

        def search_residuals(x, searched=searched, search_constants=search_constants):
            apply(search_constants(x))
            return [math.log(size_of(*r["case"]).search_seconds / r["detail"]["lower_bound"]) for r in searched]

        c = search_constants(_least_squares(search_residuals, 2))
    paths = sorted({r["path"] for r in good} - {"rate"})  # a given rate is one plain solve: "rate" follows "plain"

    def total_constants(x):
        out = copy.deepcopy(c)
        out["ESTIMATE_SECONDS_PER_MODE"] = c["ESTIMATE_SECONDS_PER_MODE"] * math.exp(x[0])
        out["ESTIMATE_SECONDS_FIXED"] = c["ESTIMATE_SECONDS_FIXED"] * math.exp(x[1])
        for p, v in zip(paths, x[2:]):
            out["ESTIMATE_PATH_ITERATIONS"][p] = c["ESTIMATE_PATH_ITERATIONS"][p] * math.exp(v)
        out["ESTIMATE_PATH_ITERATIONS"]["rate"] = out["ESTIMATE_PATH_ITERATIONS"]["plain"]
        return out

    def total_residuals(x):
        apply(total_constants(x))
        return [math.log(size_of(*r["case"]).total_seconds / r["cpu"]) for r in good]

    c = total_constants(_least_squares(total_residuals, 2 + len(paths)))
    apply(c)
    return c


def table(rows: list) -> str:
    """Per path and size: the whole request's estimate, measured CPU and their ratio, and its parts (Newton steps
    estimated / run, the lower-bound search estimated / measured), memory estimated and resident."""
    from solver import compiled

    lines = ["| path | family | n | n_drop | CPU measured | estimate | est./meas. | Newton steps est./run "
             "| search est./meas. | memory est. | peak RSS above base | outcome |", "|---" * 12 + "|"]
    for r in rows:
        size = size_of(*r["case"])
        ratio = f"{size.total_seconds / r['cpu']:.2f}" if r.get("cpu") else "-"
        steps = compiled._steps(r["path"], size.lmi_size, size.solves)
        lb = r.get("detail", {}).get("lower_bound", 0.0)
        search = f"{fmt(size.search_seconds)} / {fmt(lb)}" if lb else "-"
        lines.append(f"| {r['path']} | {r['case'][0]} | {r['n']} | {r['case'][1]} "
                     f"| {fmt(r['cpu']) if r.get('cpu') else r.get('note', '-')} | {fmt(size.total_seconds)} "
                     f"| {ratio} | {steps:.0f} / {_steps(r)[0] or '-'} | {search} | {size.memory / 2**20:.3g} MiB "
                     f"| {r.get('rss', 0) / 2**20:.3g} MiB | {r.get('outcome', '-')} |")
    return "\n".join(lines)


def error_summary(rows: list) -> str:
    """est./measured per path (its range and sizes), and over every path; memory est./resident."""
    ratios, memory = {}, []
    for r in rows:
        if r.get("fit"):
            size = size_of(*r["case"])
            ratios.setdefault(r["path"], []).append((size.total_seconds / r["cpu"], r["n"]))
            if r.get("rss", 0) > 16 * 2**20:  # below that the resident growth is the allocator's noise
                memory.append((size.memory / r["rss"], r["path"], r["n"]))
    out = []
    for path, rs in ratios.items():
        lo, hi = min(rs), max(rs)
        out.append(f"{path}: est./measured {lo[0]:.2f} (n = {lo[1]}) .. {hi[0]:.2f} (n = {hi[1]})")
    every = [x for rs in ratios.values() for x, _ in rs]
    if every:
        worst = max(max(every), 1 / min(every))
        out.append(f"every path: {min(every):.2f} .. {max(every):.2f} (worst factor {worst:.2f}; "
                   f"{sum(0.5 <= x <= 2 for x in every)} of {len(every)} within 0.5 .. 2)")
    if memory:
        lo = min(memory)
        out.append(f"memory est./peak resident growth (rows above 16 MiB): {lo[0]:.2f} ({lo[1]}, n = {lo[2]}) .. "
                   f"{max(memory)[0]:.2f}")
    return "\n".join(out)


def measure(only: set, cap: float, mem_limit: float, save: str = "") -> list:
    """Every case of :data:`CASES` (of the paths ``only``, or all) in a child process of its own; the rows
    (``save``: also written to that JSON file after each case)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one thread: CPU time = work
        os.environ[var] = "1"
    with open("/proc/loadavg") as fh:
        load = " ".join(fh.read().split()[:3])
    print(f"size estimate vs measured designs; load average {load}; CPU time per design", flush=True)
    rows = []
    for path, fam_name, n_drop, kw in CASES:
        if only and path not in only:
            continue
        out = run_child("from bench.size_calibration import child_detail",
                        f"child_detail({fam_name!r}, {n_drop}, {kw!r}, {cap})", mem_limit, 3 * cap + 60)
        fam, _ = request(fam_name, n_drop, kw)
        row = {"path": path, "case": (fam_name, n_drop, kw), "n": fam.n_states, **out}
        row["fit"] = row.get("outcome") in ("stabilized", "infeasible", "not_certified") and row.get("cpu", 0) > 0
        rows.append(row)
        print(f"  {path} {fam_name} n_drop={n_drop}: {fmt(row['cpu']) if 'cpu' in row else row.get('note')} "
              f"{row.get('outcome', '')} solves={row.get('solves', '-')}", flush=True)
        if save:
            with open(save, "w") as fh:
                json.dump(rows, fh)
    return rows


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m bench size", description=__doc__.splitlines()[0])
    p.add_argument("--cap", type=float, default=120.0, help="time limit of each design (s)")
    p.add_argument("--mem-limit", type=float, default=6.0, help="address-space cap per design, GB")
    p.add_argument("--paths", default="", help="only these paths, e.g. plain,auto")
    p.add_argument("--no-fit", action="store_true", help="the table with today's constants only")
    p.add_argument("--save", default="", help="write the measured rows to this JSON file")
    p.add_argument("--load", default="",
                   help="fit to the rows of these JSON files (comma-separated, from --save) instead of measuring")
    a = p.parse_args(argv)
    only = set(a.paths.split(",")) - {""}
    if a.load:
        rows = []
        for name in a.load.split(","):
            with open(name) as fh:
                rows += [dict(r, case=tuple(r["case"])) for r in json.load(fh) if not only or r["path"] in only]
        print(f"size estimate vs {len(rows)} designs measured earlier ({a.load})")
    else:
        rows = measure(only, a.cap, a.mem_limit, a.save)
    print("\ntoday's constants:")
    print(table(rows))
    print(error_summary(rows))
    if not a.no_fit:
        fitted = fit(rows, constants())
        apply(fitted)
        print("\nfitted constants (least squares on log CPU time), for solver/compiled.py:")
        for k in NAMES:
            print(f"{k} = {fitted[k]:.3g}")
        for k in DICTS:
            print(f"{k} = {{" + ", ".join(f'"{p}": {v:.3g}' for p, v in fitted[k].items()) + "}")
        print(table(rows))
        print(error_summary(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
