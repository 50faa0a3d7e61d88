"""``python -m bench performance``: certified cost and H-infinity brackets on the paper's DC motor.

For n_drop = 1..5 (h = 0.1 s, the three inertias of eq. 19/20): each objective's certified upper bound, the worst
periodic pattern's value (lower bound), the relative gap, the largest gain entry and the wall time of the whole
``design`` call (SDP, re-checks and the lower-bound search), of which building and solving the SDP ("SDP": cvxpy
build + Clarabel's solve time), beside the plain ``lmi`` design's time.  Objectives:
cost (Q = I, R = 1, mean over x0 of covariance I), cost from x0 = (-3, 2) without and with an input limit
|u| <= 0.5 V, and the l2 gain from an input disturbance (E_l = G_l) to z = [x; u].  Also the paper's eq. 23
gains analysed for the same figures (n_drop = 3).

Options: ``--n-drop 1,2,3`` (subset), ``--repeats R`` (median of R timed designs, default 1).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from solver import PlantFamily, analyze, design

EQ23 = np.array([[[-4.0726, -0.0823]], [[0.0024, 0.0375]], [[0.0006, 0.0114]]])
X0 = [-3.0, 2.0]
U_MAX = 0.5


def cases(fam: PlantFamily):
    E = list(fam.G)
    return [
        ("cost (trace)", {"objective": "cost"}),
        ("cost (x0)", {"objective": "cost", "x0": X0}),
        (f"cost (x0), u_max = {U_MAX}", {"objective": "cost", "x0": X0, "u_max": [U_MAX]}),
        ("hinf (w at the input)", {"objective": "hinf", "disturbance": E}),
    ]


def timed(fn, repeats: int):
    times, out = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return out, statistics.median(times)


def fmt(v, digits=6):
    return "-" if v is None else f"{v:.{digits}g}"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if "--speed" in argv:  # the timing table (bench/perf_speed.py)
        from . import perf_speed

        return perf_speed.main([x for x in argv if x != "--speed"])
    p = argparse.ArgumentParser(prog="python -m bench performance")
    p.add_argument("--n-drop", default="1,2,3,4,5")
    p.add_argument("--repeats", type=int, default=1)
    a = p.parse_args(argv)
    fam = PlantFamily.paper_example(0.1)
    drops = [int(x) for x in a.n_drop.split(",")]
    print("| objective | n_drop | upper | lower | gap | max abs K | time (s) | SDP (s) | plain lmi (s) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, kwargs in cases(fam):
        for N in drops:
            res, t = timed(lambda: design(fam, N, **kwargs), a.repeats)
            _, t_lmi = timed(lambda: design(fam, N, decay_rate=None), max(a.repeats, 3))  # one SDP, as the objectives
            perf = res.performance
            gains = "-" if res.gains is None else f"{np.max(np.abs(res.gains)):.3g}"
            sdp = res.timings.get("setup", 0.0) + res.timings.get("solver", 0.0)
            print(f"| {name} | {N} | {fmt(perf.upper)} | {fmt(perf.lower)} | {fmt(perf.gap, 2)} | {gains} | "
                  f"{t:.2f} | {sdp:.3f} | {t_lmi:.3f} |" if perf is not None else
                  f"| {name} | {N} | {res.outcome} | - | - | {gains} | {t:.2f} | {sdp:.3f} | {t_lmi:.3f} |")
    rep = analyze(fam, EQ23, 3, weights=(np.eye(2), np.eye(1)), x0=None, disturbance=list(fam.G), bounds="none")
    for perf, name in ((rep.cost, "cost (trace)"), (rep.hinf, "hinf (w at the input)")):
        print(f"| eq. 23 gains, {name} | 3 | {fmt(perf.upper)} | {fmt(perf.lower)} | {fmt(perf.gap, 2)} | "
              f"{np.max(np.abs(EQ23)):.3g} | {rep.timings['total']:.2f} | - | - |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
