"""``python -m bench performance --speed``: what each objective costs beside the plain design and beside the peers.

For the paper's example (n_drop 3) and the feasible random families of ``bench/speed_bench.py`` at n = 12 and
n = 20 (r = 5, m = 2, n_drop = 10), each objective (plain ``lmi``, cost (trace), hinf with ``E_l = G_l``, u_max
= 1 per input without x0) is measured, each cell in a child process of its own (``bench/child.py``), CPU time
(``time.process_time``; load average printed):

* ``design() IPM`` / ``design() Clarabel``: the whole call with ``solver="IPM"`` / ``"CLARABEL"`` (SDP, re-checks,
  the bracket's lower-bound search); the ratios divide by the plain ``lmi`` design on the same solver;
* ``SDP Clarabel`` / ``SDP CVXOPT``: the same SDP built with cvxpy and solved alone (build + canonicalization +
  solve; for plain lmi: the solve of the compiled problem, canonicalization excluded, as in ``bench speed``).

Options: ``--cases paper,12,20``, ``--objectives lmi,cost,hinf,u_max``, ``--cap S`` (wall seconds per cell),
``--no-cvxopt``.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from .child import fmt, run_child

CASES = ("paper", 12, 20)
OBJECTIVES = ("lmi", "cost", "hinf", "u_max")
WHAT = ("design_ipm", "design_clarabel", "sdp_clarabel", "sdp_cvxopt")


def _family(case):
    from solver import PlantFamily

    from .speed_bench import N_DROP, family

    if case == "paper":
        return PlantFamily.paper_example(0.1), 3
    return family(int(case), "feasible"), N_DROP


def _request(objective: str, fam) -> dict:
    if objective == "cost":
        return {"objective": "cost"}
    if objective == "hinf":
        return {"objective": "hinf", "disturbance": list(fam.G)}
    if objective == "u_max":
        return {"u_max": [1.0] * fam.n_inputs}
    return {"decay_rate": None}


def child(case, objective: str, what: str) -> dict:
    """One measurement (run in a fresh interpreter by :func:`cell`)."""
    import warnings

    from solver import InvalidInput, design

    fam, N = _family(case)
    kw = _request(objective, fam)
    out = {}
    if what.startswith("design"):
        solver = "IPM" if what == "design_ipm" else "CLARABEL"
        # first-use costs (imports, BLAS handles, cvxpy's first canonicalization, the plain design's compiled
        # problem) out of the timing, as a user's second design has them
        if case == "paper":  # the same call once (beyond the paper size first-use costs are noise)
            design(fam, N, solver=solver, **kw)
        c0 = time.process_time()
        try:
            res = design(fam, N, solver=solver, **kw)
        except InvalidInput as err:  # the size checks refuse it before any solve
            return {"note": "refused: " + str(err).split(":")[0].replace("the ", "", 1)}
        out["cpu"] = time.process_time() - c0
        out["outcome"] = res.outcome
        out["ran"] = str(res.solver)
        return out
    import cvxpy as cp

    name = "CLARABEL" if what == "sdp_clarabel" else "CVXOPT"
    if objective == "lmi":
        from .speed_bench import child as speed_child

        cell = speed_child(case if case == "paper" else int(case), "feasible", name.lower(), 0.0)
        return {"cpu": cell["cpu"][0], "outcome": cell.get("status")}
    from solver.methods import performance
    from solver.network import ModeSet
    from solver.brackets import solve_sdp

    modes = ModeSet.from_family(fam, N)
    c0 = time.process_time()
    try:
        lifted, x0, u_max = performance.prepare(modes, "lmi", kw.get("objective", "stability"), None, None,
                                                kw.get("disturbance"), None, kw.get("u_max"), None)
    except InvalidInput as err:
        return {"note": "refused: " + str(err).split(":")[0].replace("the ", "", 1)}
    prob = performance.build(lifted, kw.get("objective", "stability"), x0, u_max, None)[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if name == "CLARABEL":
            status = solve_sdp(prob, "CLARABEL").status  # the design's tolerances
        else:
            prob.solve(solver=cp.CVXOPT)
            status = prob.status
    out["cpu"] = time.process_time() - c0
    out["outcome"] = status
    return out


def cell(case, objective: str, what: str, cap: float, mem_gb: float) -> dict:
    return run_child("from bench.perf_speed import child", f"child({case!r}, {objective!r}, {what!r})", mem_gb, cap,
                     note_chars=60)


def _cpu(c: dict) -> float:
    return float(c["cpu"]) if "cpu" in c else float("nan")


def _text(c: dict) -> str:
    if "note" in c:
        return c["note"]
    tag = "" if c.get("outcome") in ("stabilized", "optimal", "optimal_inaccurate", None) else f" ({c['outcome']})"
    ran = "" if c.get("ran") in (None, "IPM", "CLARABEL") or "ipm" in str(c.get("ran")).lower() else f" [{c['ran']}]"
    return fmt(_cpu(c)) + tag + ran


def _ratio(a: float, b: float) -> str:
    return "-" if not (np.isfinite(a) and np.isfinite(b) and b > 0) else f"{a / b:.1f}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench performance --speed")
    p.add_argument("--cases", default=",".join(str(c) for c in CASES))
    p.add_argument("--objectives", default=",".join(OBJECTIVES))
    p.add_argument("--cap", type=float, default=600.0, help="wall seconds per cell")
    p.add_argument("--mem-limit", type=float, default=6.0)
    p.add_argument("--no-cvxopt", action="store_true")
    p.add_argument("--peers-max-n", type=int, default=12,
                   help="above this n the Clarabel/CVXOPT cells of the plain lmi design are not run (minutes each)")
    a = p.parse_args(argv)
    cases = [c.strip() for c in a.cases.split(",") if c.strip()]
    objectives = [o.strip() for o in a.objectives.split(",") if o.strip()]
    load0 = os.getloadavg()
    results = {}
    for case in cases:
        for obj in objectives:
            for what in WHAT:
                big = case != "paper" and int(case) > a.peers_max_n
                if (what == "sdp_cvxopt" and a.no_cvxopt) or (big and obj == "lmi" and what != "design_ipm"):
                    results[case, obj, what] = {"note": "not run"}
                    continue
                t0 = time.perf_counter()
                results[case, obj, what] = c = cell(case, obj, what, a.cap, a.mem_limit)
                print(f"  {case} {obj} {what}: {_text(c)} ({time.perf_counter() - t0:.0f} s wall)", flush=True)
    load1 = os.getloadavg()
    print()
    print(f"Performance objectives, CPU per call ({os.cpu_count()} cpus, load average {load0[0]:.2f} at start, "
          f"{load1[0]:.2f} at the end); ratios: design() / plain lmi design() on the same solver")
    print()
    print("| case | objective | design() IPM | design() Clarabel | SDP Clarabel | SDP CVXOPT | IPM / lmi | "
          "Clarabel / lmi |")
    print("|---|---|---|---|---|---|---|---|")
    for case in cases:
        label = "paper (n=2, N=3)" if case == "paper" else f"n={case} (r=5, N=10)"
        base = {w: _cpu(results.get((case, "lmi", w), {})) for w in WHAT}
        for obj in objectives:
            cells = [results[case, obj, w] for w in WHAT]
            print(f"| {label} | {obj} | " + " | ".join(_text(c) for c in cells) + " | "
                  f"{_ratio(_cpu(cells[0]), base['design_ipm'])} | {_ratio(_cpu(cells[1]), base['design_clarabel'])} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
