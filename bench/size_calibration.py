"""``python -m bench size``: fit the size estimate's constants to measured designs (issue 29, item 4).

:func:`solver.compiled.design_size` estimates the CPU time and memory of a whole design request from its
dimensions alone; the library refuses (:func:`solver.design`, :func:`solver.analyze`) and the service limits
(``NCS_JOB_TIME_LIMIT``, ``NCS_WORKER_MEMORY_MB``) with it.  This script measures designs on every path (plain, a
given rate, ``"auto"``, ``"max"``, cost, H-infinity, input limits, switched, ccl, a network; small to large n and
n_drop), each in a child process of its own (CPU time by ``time.process_time``, the peak resident set above the
interpreter's by ``getrusage``), then fits by least squares on log time

* the scale of the flop rates (:data:`~solver.compiled.ESTIMATE_FLOPS_PER_SECOND` and
  :data:`~solver.compiled.ESTIMATE_FLOPS_PER_SIDE` together), :data:`~solver.compiled.ESTIMATE_SECONDS_PER_BLOCK`,
  :data:`~solver.compiled.ESTIMATE_SECONDS_PER_MODE`, :data:`~solver.compiled.ESTIMATE_SECONDS_FIXED`;
* each path's :data:`~solver.compiled.ESTIMATE_SOLVE_WEIGHT` (plain and rate stay 1),

and prints the table of estimate / measured per path and size with the constants to put in solver/compiled.py.
``--no-fit`` prints the table of today's constants only.  Designs that fail or hit ``--cap`` are listed but not
fitted.  Runs about 5 to 10 minutes of CPU.
"""

from __future__ import annotations

import math
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
    ("cost", "paper", 3, {"objective": "cost"}),
    ("cost", "pend", 5, {"objective": "cost"}),
    ("cost", "r8", 10, {"objective": "cost"}),
    ("hinf", "paper", 3, {"objective": "hinf", "disturbance": "ones"}),
    ("hinf", "r8", 10, {"objective": "hinf", "disturbance": "ones"}),
    ("u_max", "paper", 3, {"u_max": "ones", "decay_rate": None}),
    ("u_max", "r8", 10, {"u_max": "ones", "decay_rate": None}),
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


def child(fam_name: str, n_drop: int, kw: dict, cap: float) -> dict:
    """One measured design in this (fresh) process: CPU, outcome, solves, peak RSS above the warmed-up one."""
    import resource

    from solver import PlantFamily, design

    design(PlantFamily.paper_example(0.1), 3)  # first-use costs (imports, BLAS handles, caches)
    fam, kw = request(fam_name, n_drop, kw)
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
    return out


def size_of(fam_name: str, n_drop: int, kw: dict):
    from solver.design import request_size

    fam, kw = request(fam_name, n_drop, kw)
    return request_size(kw.pop("method", "lmi"), fam, n_drop, decay_rate=kw.get("decay_rate", "auto"),
                        objective=kw.get("objective", "stability"), u_max=kw.get("u_max"),
                        disturbance=kw.get("disturbance"), network=kw.get("network"))


NAMES = ("ESTIMATE_FLOPS_PER_SECOND", "ESTIMATE_FLOPS_PER_SIDE", "ESTIMATE_SECONDS_PER_BLOCK",
         "ESTIMATE_SECONDS_PER_MODE", "ESTIMATE_SECONDS_FIXED")


def constants() -> dict:
    from solver import compiled

    return {**{k: getattr(compiled, k) for k in NAMES}, "weights": dict(compiled.ESTIMATE_SOLVE_WEIGHT)}


def apply(c: dict) -> None:
    from solver import compiled

    for k in NAMES:
        setattr(compiled, k, c[k])
    compiled.ESTIMATE_SOLVE_WEIGHT.clear()
    compiled.ESTIMATE_SOLVE_WEIGHT.update(c["weights"])


def fit(rows: list, start: dict) -> dict:
    """Least squares on log(estimate / measured) over the rows that finished, from the constants ``start``."""
    import numpy as np
    from scipy.optimize import least_squares

    good = [r for r in rows if r.get("fit")]
    paths = sorted({r["path"] for r in good} - {"plain", "rate"})

    def unpack(x):
        c = {"ESTIMATE_FLOPS_PER_SECOND": start["ESTIMATE_FLOPS_PER_SECOND"] * math.exp(x[0]),
             "ESTIMATE_FLOPS_PER_SIDE": start["ESTIMATE_FLOPS_PER_SIDE"] * math.exp(x[0]),
             "ESTIMATE_SECONDS_PER_BLOCK": start["ESTIMATE_SECONDS_PER_BLOCK"] * math.exp(x[1]),
             "ESTIMATE_SECONDS_PER_MODE": start["ESTIMATE_SECONDS_PER_MODE"] * math.exp(x[2]),
             "ESTIMATE_SECONDS_FIXED": start["ESTIMATE_SECONDS_FIXED"] * math.exp(x[3]),
             "weights": dict(start["weights"])}
        for p, v in zip(paths, x[4:]):
            c["weights"][p] = start["weights"][p] * math.exp(v)
        return c

    def residuals(x):
        apply(unpack(x))
        # a weak pull to today's constants keeps the directions the data do not see where they were
        return np.concatenate([[math.log(size_of(*r["case"]).total_seconds / r["cpu"]) for r in good],
                               0.05 * np.asarray(x)])

    sol = least_squares(residuals, np.zeros(4 + len(paths)), method="lm" if len(good) > 4 + len(paths) else "trf")
    return unpack(sol.x)


def table(rows: list) -> str:
    lines = ["| path | family | n | n_drop | solves (est./run) | CPU measured | estimate | est./meas. "
             "| memory est. | peak RSS above base | outcome |", "|---" * 11 + "|"]
    for r in rows:
        size = size_of(*r["case"])
        ratio = f"{size.total_seconds / r['cpu']:.2f}" if r.get("cpu") else "-"
        lines.append(f"| {r['path']} | {r['case'][0]} | {r['n']} | {r['case'][1]} | {size.solves}/{r.get('solves', '-')} "
                     f"| {fmt(r['cpu']) if r.get('cpu') else r.get('note', '-')} | {fmt(size.total_seconds)} "
                     f"| {ratio} | {size.memory / 2**20:.3g} MiB | {r.get('rss', 0) / 2**20:.3g} MiB "
                     f"| {r.get('outcome', '-')} |")
    return "\n".join(lines)


def error_summary(rows: list) -> str:
    ratios = {}
    for r in rows:
        if r.get("fit"):
            ratios.setdefault(r["path"], []).append(size_of(*r["case"]).total_seconds / r["cpu"])
    out = []
    for path, rs in ratios.items():
        out.append(f"{path}: est./measured {min(rs):.2f} .. {max(rs):.2f}")
    every = [x for rs in ratios.values() for x in rs]
    if every:
        worst = max(max(every), 1 / min(every))
        out.append(f"every path: {min(every):.2f} .. {max(every):.2f} (worst factor {worst:.2f})")
    return "\n".join(out)


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m bench size", description=__doc__.splitlines()[0])
    p.add_argument("--cap", type=float, default=120.0, help="time limit of each design (s)")
    p.add_argument("--mem-limit", type=float, default=6.0, help="address-space cap per design, GB")
    p.add_argument("--paths", default="", help="only these paths, e.g. plain,auto")
    p.add_argument("--no-fit", action="store_true", help="the table with today's constants only")
    a = p.parse_args(argv)
    with open("/proc/loadavg") as fh:
        load = " ".join(fh.read().split()[:3])
    print(f"size estimate vs measured designs; load average {load}; CPU time per design", flush=True)
    only = set(a.paths.split(",")) - {""}
    rows = []
    for path, fam_name, n_drop, kw in CASES:
        if only and path not in only:
            continue
        out = run_child("from bench.size_calibration import child",
                        f"child({fam_name!r}, {n_drop}, {kw!r}, {a.cap})", a.mem_limit, 3 * a.cap + 60)
        fam, _ = request(fam_name, n_drop, kw)
        row = {"path": path, "case": (fam_name, n_drop, kw), "n": fam.n_states, **out}
        row["fit"] = row.get("outcome") in ("stabilized", "infeasible", "not_certified") and row.get("cpu", 0) > 0
        rows.append(row)
        print(f"  {path} {fam_name} n_drop={n_drop}: {fmt(row['cpu']) if 'cpu' in row else row.get('note')} "
              f"{row.get('outcome', '')} solves={row.get('solves', '-')}", flush=True)
    print("\ntoday's constants:")
    print(table(rows))
    print(error_summary(rows))
    if not a.no_fit:
        fitted = fit(rows, constants())
        apply(fitted)
        print("\nfitted constants (least squares on log CPU time):")
        for k in NAMES:
            print(f"{k} = {fitted[k]:.3g}")
        print("ESTIMATE_SOLVE_WEIGHT = {" + ", ".join(f'"{k}": {v:.3g}' for k, v in fitted["weights"].items())
              + "}")
        print(table(rows))
        print(error_summary(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
