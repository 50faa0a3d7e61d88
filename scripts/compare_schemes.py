"""Predictive buffer versus the non-predictive baselines the paper improves on.

For the paper's example (h = 0.1 s) and a marginally stable family (a double
integrator and an undamped oscillator, h = 0.2 s), print for each scheme the
largest n_drop with a stabilizing design and the best certified per-sample
decay rate at n_drop = 3.

    python scripts/compare_schemes.py [--method lmi|switched] [--n-drop-max 12]
"""

from __future__ import annotations

import argparse
import time

from solver import PlantFamily, design
from solver.margins import max_n_drop

SCHEMES = ("predictive", "hold", "zero")


def families():
    yield "paper example (eq. 19, h = 0.1 s)", PlantFamily.paper_example(0.1)
    A = [[[0.0, 1.0], [0.0, 0.0]], [[0.0, 1.0], [-1.0, 0.0]]]
    B = [[[0.0], [1.0]]] * 2
    yield "double integrator + oscillator (h = 0.2 s)", PlantFamily.from_continuous(A, B, 0.2)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--method", default="lmi", choices=["lmi", "switched"])
    parser.add_argument("--n-drop-max", type=int, default=12)
    args = parser.parse_args(argv)
    start = time.perf_counter()
    print(f"method = {args.method}; n_drop searched up to {args.n_drop_max}; decay rate at n_drop = 3 "
          f"(bisection, tolerance 1e-3)\n")
    print(f"| {'family':44s} | {'scheme':10s} | {'largest n_drop':>14s} | {'best decay rate':>15s} |")
    print(f"|{'-' * 46}|{'-' * 12}|{'-' * 16}|{'-' * 17}|")
    for name, fam in families():
        for scheme in SCHEMES:
            margin = max_n_drop(fam, args.method, n_drop_max=args.n_drop_max, scheme=scheme)
            shown = "none" if margin.margin is None else str(margin.margin)
            if margin.margin == args.n_drop_max and margin.curve[-1]["outcome"] == "stabilized":
                shown = f">= {margin.margin}"
            rate = design(fam, 3, method=args.method, scheme=scheme, decay_rate="max")
            shown_rate = f"{rate.decay_rate:.4f}" if rate.outcome == "stabilized" else rate.outcome
            print(f"| {name:44s} | {scheme:10s} | {shown:>14s} | {shown_rate:>15s} |")
    print(f"\n({time.perf_counter() - start:.1f} s)")


if __name__ == "__main__":
    main()
