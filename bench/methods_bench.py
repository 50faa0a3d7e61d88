"""``python -m bench methods``: which method when, measured.

For a few families, every method (``lmi``, ``switched``, ``ccl``) with and without
``decay_rate="max"`` (ccl has no rate option): the outcome, the median process CPU time
of one whole ``design()`` call (``time.process_time``: robust to a shared machine, unlike
wall time) and its ratio to ``lmi`` with the same rate option, the per-sample decay rate
the design's own certificate proves (``res.decay_rate``, ``decay_rate="max"`` only), the
best rate ``analyze`` certifies for the gains (``bounds="all"``: common quadratic and
switched certificates, the same yardstick for every row) and how far the gains are from
``lmi``'s with the same rate option (``max |K - K_lmi| / max |K_lmi|``).  The analyses are
not timed.

Options::

    --repeats N     timed designs per cell (default 5; median)
    --cases a,b     subset of the case names below
    --calls         instead: whole design and analyze calls on the paper example under
                    ``solver="AUTO"`` and ``solver="CLARABEL"``, median wall [process CPU]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from solver import PlantFamily, analyze, design

from .cases import random_family


def unstable_pair_family(seed: int) -> PlantFamily:
    """Seeded 2-state, 3-mode, single-input family, every mode's spectral radius in [1.0, 1.1].

    Seed 5 is one where no common quadratic design exists (``lmi`` proves it) but a
    switched one does; seed 6 is one both methods stabilize.
    """
    rng = np.random.default_rng(seed)
    F = rng.normal(size=(3, 2, 2))
    F = F / np.max(np.abs(np.linalg.eigvals(F)), axis=1)[:, None, None] * rng.uniform(1.0, 1.1, size=(3, 1, 1))
    return PlantFamily(F=F, G=rng.normal(size=(3, 2, 1)), name=f"unstable pair seed={seed}")


def marginal_family() -> PlantFamily:
    """A double integrator and an undamped oscillator (marginally stable open loop), h = 0.2 s."""
    A = [[[0.0, 1.0], [0.0, 0.0]], [[0.0, 1.0], [-1.0, 0.0]]]
    return PlantFamily.from_continuous(A, [[[0.0], [1.0]]] * 2, 0.2)


#: name -> (description, family builder, n_drop)
CASES = {
    "paper": ("paper example, h = 0.1 s (n=2, r=3, m=1)", lambda: PlantFamily.paper_example(0.1), 3),
    "marginal": ("double integrator + oscillator, h = 0.2 s (n=2, r=2, m=1)", marginal_family, 3),
    "random4": ("random n=4, r=3, m=2, seed 2", lambda: random_family(4, 3, 2, seed=2, spread=0.3), 4),
    "pair6": ("seeded unstable n=2, r=3, m=1, seed 6", lambda: unstable_pair_family(6), 3),
    "pair5": ("seeded unstable n=2, r=3, m=1, seed 5 (no common quadratic design)",
              lambda: unstable_pair_family(5), 3),
}

RUNS = (("lmi", None), ("switched", None), ("ccl", None), ("lmi", "max"), ("switched", "max"))


def _cpu(fn, repeats: int):
    times, res = [], None
    for _ in range(repeats):
        t0 = time.process_time()
        res = fn()
        times.append(time.process_time() - t0)
    return statistics.median(times), res


def _best_rate(family, res) -> float | None:
    if res.outcome != "stabilized":
        return None
    return analyze(family, res.gains, res.n_drop, bounds="all").decay_rate


def _fmt_time(s: float) -> str:
    return f"{s * 1e3:.1f} ms" if s < 1 else f"{s:.2f} s"


def measure(name: str, repeats: int) -> list[dict]:
    """Rows of the table for one case (the first design of each cell is a warm-up, not timed)."""
    _desc, build, n_drop = CASES[name]
    family = build()
    rows, lmi_rows = [], {}
    for method, rate_option in RUNS:
        def run(method=method, rate_option=rate_option):
            return design(family, n_drop, method=method, decay_rate=rate_option)

        run()  # warm-up: compiled problems and caches, as in a long-lived process
        cpu, res = _cpu(run, 1 if method == "ccl" else repeats)
        row = {"case": name, "method": method, "decay_rate": rate_option, "outcome": res.outcome,
               "cpu": cpu, "proven": res.decay_rate if res.outcome == "stabilized" else None,
               "rate": _best_rate(family, res), "gains": res.gains}
        if method == "lmi":
            lmi_rows[rate_option] = row
        rows.append(row)
    for row in rows:
        base = lmi_rows[row["decay_rate"]]
        row["x_lmi"] = row["cpu"] / base["cpu"]
        if row["method"] == "lmi":
            row["same_gains"] = "-"
        elif row["outcome"] != "stabilized" or base["outcome"] != "stabilized":
            row["same_gains"] = "n/a"
        else:
            diff = np.max(np.abs(row["gains"] - base["gains"])) / max(np.max(np.abs(base["gains"])), 1e-12)
            row["same_gains"] = f"{diff:.1%}"
    return rows


def table(rows: list[dict]) -> str:
    out = ["| family, n_drop | method | decay_rate | outcome | CPU per design | x lmi (same decay_rate) "
           "| rate proven by the design | best certified rate of the gains | gains vs lmi |",
           "|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        desc, _build, n_drop = CASES[row["case"]]
        proven = "-" if row["proven"] is None else f"{row['proven']:.4f}"
        rate = "-" if row["rate"] is None else f"{row['rate']:.4f}"
        option = '`"max"`' if row["decay_rate"] else "-"
        out.append(f"| {desc}, N = {n_drop} | `{row['method']}` | {option} | {row['outcome']} | "
                   f"{_fmt_time(row['cpu'])} | {row['x_lmi']:.1f}x | {proven} | {rate} | {row['same_gains']} |")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench methods", description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--calls", action="store_true")
    args = p.parse_args(argv)
    if args.calls:
        print(f"paper example, h = 0.1 s, n_drop = 3: median of {args.repeats * 4} calls, wall [process CPU], "
              f"load average {', '.join(f'{x:.1f}' for x in os.getloadavg())}\n")
        print(calls_table(args.repeats * 4))
        print(f"\nload average at the end {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
        return 0
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"which method when: median process CPU of {args.repeats} designs (ccl: 1), load average {load}\n")
    rows = []
    for name in args.cases.split(","):
        rows.extend(measure(name, args.repeats))
    print(table(rows))
    print(f"\nload average at the end {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    return 0


def calls_table(repeats: int) -> str:
    """Whole calls on the paper example under ``solver="AUTO"`` and ``solver="CLARABEL"``: median wall [CPU]."""
    family = PlantFamily.paper_example(0.1)
    gains = design(family, 3).gains
    calls = [
        ("`design(fam, 3)` (`lmi`)", lambda s: design(family, 3, solver=s)),
        ('`design(fam, 3, decay_rate="max")`', lambda s: design(family, 3, decay_rate="max", solver=s)),
        ('`design(fam, 3, method="switched")`', lambda s: design(family, 3, method="switched", solver=s)),
        ("`analyze(fam, gains, 3)`", lambda s: analyze(family, gains, 3, solver=s)),
    ]
    out = ["| call | `AUTO` | `solver=\"CLARABEL\"` |", "|---|---|---|"]
    for label, call in calls:
        cells = []
        for solver in ("AUTO", "CLARABEL"):
            call(solver)  # warm-up: compiled problems and caches
            walls, cpus = [], []
            for _ in range(repeats):
                w0, c0 = time.perf_counter(), time.process_time()
                call(solver)
                walls.append(time.perf_counter() - w0)
                cpus.append(time.process_time() - c0)
            cells.append(f"{_fmt_time(statistics.median(walls))} [{_fmt_time(statistics.median(cpus))}]")
        out.append(f"| {label} | {cells[0]} | {cells[1]} |")
    return "\n".join(out)
