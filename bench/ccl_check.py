"""``python -m bench ccl-check [--count N]``: the IPM path of ``ccl`` against the Clarabel path.

On seeded random small families (n=2, m=1, r=2, n_drop=3, as tests/solver/test_design.py):

* default start (Step 1 a feasibility problem): the verdicts must agree.  The
  iterates need not: a feasibility problem has no unique answer, and the IPM
  path's Step 1 is a centred max-margin point (solver/methods/ccl.py), not
  Clarabel's.
* ``ccl_start="min_trace"`` (every SDP has a unique optimum): verdicts, the number
  of CCL iterations and the objective of every iterate are compared.

Every "stabilized" is the certify path's float64 re-check in both solvers.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def random_family(seed, n=2, m=1, r=2, scale=(0.7, 1.6)):
    from solver import PlantFamily

    rng = np.random.default_rng(seed)
    F = rng.normal(size=(r, n, n))
    F = F / np.max(np.abs(np.linalg.eigvals(F)), axis=1)[:, None, None] * rng.uniform(*scale, size=(r, 1, 1))
    return PlantFamily(F=F, G=rng.normal(size=(r, n, m)))


def compare(seed: int, start: str, max_iter: int = 25, verbose: bool = False) -> dict:
    from solver import design

    fam = random_family(seed)
    out = {"seed": seed, "start": start}
    for solver in ("CLARABEL", "IPM"):
        t0 = time.perf_counter()
        res = design(fam, n_drop=3, method="ccl", max_iter=max_iter, ccl_start=start, solver=solver)
        if verbose:
            print(solver, [round(r.objective, 5) for r in res.history])
        out[solver] = res
        out[solver + "_time"] = time.perf_counter() - t0
    a, b = out["CLARABEL"], out["IPM"]
    out["same_outcome"] = a.outcome == b.outcome
    k = min(len(a.history), len(b.history))
    oa = np.array([r.objective for r in a.history[:k]])
    ob = np.array([r.objective for r in b.history[:k]])
    out["obj_rel"] = float(np.max(np.abs(oa - ob) / (1.0 + np.abs(oa)))) if k else 0.0
    out["iters"] = (len(a.history), len(b.history))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench ccl-check")
    ap.add_argument("--count", type=int, default=20)
    ap.add_argument("--start", choices=("feasibility", "min_trace"), action="append")
    args = ap.parse_args(argv)
    bad = 0
    for start in args.start or ("feasibility", "min_trace"):
        print(f"ccl_start={start}: seed  Clarabel outcome (iters)  IPM outcome (iters)  max rel. objective diff  times")
        for seed in range(args.count):
            c = compare(seed, start)
            a, b = c["CLARABEL"], c["IPM"]
            flag = "" if c["same_outcome"] else "  <-- verdicts differ"
            if not c["same_outcome"]:
                bad += 1
            diff = f"{c['obj_rel']:.1e}" if start == "min_trace" else "-"
            print(f"  {seed:3d}  {a.outcome:14s} ({c['iters'][0]:2d})  {b.outcome:14s} ({c['iters'][1]:2d})  {diff:>8s}"
                  f"  {c['CLARABEL_time']:.2f} s / {c['IPM_time']:.2f} s{flag}")
    print(f"{bad} verdict disagreements")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
