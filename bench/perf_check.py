"""``python -m bench perf-check [--count N]``: the performance designs on the IPM against Clarabel.

For seeded random small families (n 2..4, 1..3 plant modes, n_drop 1..4, m 1..2; :func:`draw`) every objective
(:data:`OBJECTIVES`: cost (trace), cost (x0), hinf, u_max with x0, u_max + cost with x0) is designed twice,
``design(..., solver="IPM")`` and ``design(..., solver="CLARABEL")``, and compared: the same outcome, and the
certified figure within ``--tol`` (1e-6) relative: ``performance.upper`` for cost/hinf, for u_max alone the radius
``lambda_max(X)^(-1/2)`` of the largest ball inside the invariant set (what both solvers maximize).  A design that answers with a solver other
than the IPM when the IPM was asked for (``res.solver``), or raises, is counted as "IPM not available for
objective X" rather than as an agreement.  Both figures are certified bounds on the same SDP's optimum, so a
pair outside the tolerance says which solver stopped short: the one with the worse figure (or the one that proves
nothing where the other proves); pairs where that is Clarabel are counted apart.  Prints the counts per objective
and the worst disagreements; exits non-zero when the IPM is the worse one anywhere.
"""

from __future__ import annotations

import argparse
import os
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from .cases import random_family

OBJECTIVES = ("cost (trace)", "cost (x0)", "hinf", "u_max", "u_max + cost")


def draw(seed: int):
    """``(family, n_drop, x0, u_max, description)`` of one seeded small family (modes near a nominal plant)."""
    rng = np.random.default_rng(10_000 + seed)
    n, r, N, m = int(rng.integers(2, 5)), int(rng.integers(1, 4)), int(rng.integers(1, 5)), int(rng.integers(1, 3))
    fam = random_family(n, r, m, seed=seed, rho=(0.8, 1.15), spread=float(rng.uniform(0.05, 0.3)))
    x0 = rng.standard_normal(n)
    u_max = 10.0 ** rng.uniform(-1.5, 1.0, m)  # some limits bind, some cannot be met from x0
    return fam, N, x0, u_max, f"seed {seed}: n={n} r={r} N={N} m={m}"


def request(objective: str, fam, x0, u_max) -> dict:
    if objective == "cost (trace)":
        return {"objective": "cost"}
    if objective == "cost (x0)":
        return {"objective": "cost", "x0": x0}
    if objective == "hinf":
        return {"objective": "hinf", "disturbance": list(fam.G)}
    if objective == "u_max":  # one SDP for both solvers (the default rate's search would pick a rate per solver)
        return {"u_max": u_max, "x0": x0, "decay_rate": None}
    return {"objective": "cost", "u_max": u_max, "x0": x0}


def figure(res) -> float | None:
    """The certified number a design reports for its objective (None when there is none): for cost and hinf the
    quadratic certificate's bound (what the SDP optimizes; the reported cost ``upper`` may be the prefix tree's
    tighter one, docs/design.md §8.4)."""
    if res.performance is not None and res.performance.certificate_upper is not None:
        return float(res.performance.certificate_upper)
    if res.invariant_set is not None:
        X = np.asarray(res.invariant_set)
        return float(np.linalg.eigvalsh(0.5 * (X + X.T))[-1] ** -0.5)
    return None


@dataclass
class Tally:
    compared: int = 0
    same_verdict: int = 0
    within: int = 0
    ipm_better: int = 0  # outside tol, but the IPM's certified figure is the better one (or only it proves)
    unavailable: int = 0
    reasons: set = field(default_factory=set)
    worst: list = field(default_factory=list)  # (relative difference or inf for a verdict mismatch, text)


def compare(seed: int, objective: str, tol: float, tally: Tally) -> None:
    from solver import design

    fam, N, x0, u_max, desc = draw(seed)
    kw = request(objective, fam, x0, u_max)
    try:
        mine = design(fam, N, solver="IPM", **kw)
    except Exception as err:  # noqa: BLE001  (an objective the IPM does not take yet)
        tally.unavailable += 1
        tally.reasons.add(f"{type(err).__name__}: {err}"[:120])
        return
    if str(mine.solver).upper() != "IPM":  # nothing to compare: the reference is not run
        tally.unavailable += 1
        tally.reasons.add(f"solver='IPM' ran {mine.solver}")
        return
    ref = design(fam, N, solver="CLARABEL", **kw)
    tally.compared += 1
    if mine.outcome != ref.outcome:
        tally.ipm_better += mine.outcome == "stabilized" and ref.outcome == "not_converged"
        tally.worst.append((np.inf, f"{desc}: IPM {mine.outcome} vs Clarabel {ref.outcome}"))
        return
    tally.same_verdict += 1
    a, b = figure(mine), figure(ref)
    if a is None and b is None:
        tally.within += 1
        return
    if a is None or b is None:
        tally.worst.append((np.inf, f"{desc}: a figure only from {'Clarabel' if a is None else 'the IPM'}"))
        return
    rel = abs(a - b) / max(abs(b), 1e-300)
    tally.within += rel <= tol
    # both figures are certified (re-checked) bounds of the same SDP's optimum: the smaller cost or gain, the
    # larger ball radius, is the closer one, so a gap says which solver stopped short
    tally.ipm_better += rel > tol and (a > b if objective == "u_max" else a < b)
    tally.worst.append((rel, f"{desc}: IPM {a:.10g} vs Clarabel {b:.10g} ({mine.outcome})"))


def run(count: int, tol: float = 1e-6, objectives=OBJECTIVES, first_seed: int = 0, out=print,
        progress=None) -> dict:
    """Cross-check ``count`` families; returns ``{objective: Tally}`` (also printed through ``out``).

    ``progress``: called with one line per family (the running counts), e.g. ``print`` for long runs.
    """
    tallies = {obj: Tally() for obj in objectives}
    start = time.process_time()
    for seed in range(first_seed, first_seed + count):
        for obj in objectives:
            try:
                compare(seed, obj, tol, tallies[obj])
            except Exception:  # noqa: BLE001  (the Clarabel reference itself failed: a bug to see, not to hide)
                tallies[obj].worst.append((np.inf, f"seed {seed}: error {traceback.format_exc(limit=1)[-200:]}"))
        if progress is not None:
            progress(f"seed {seed}: " + "; ".join(f"{o}: {t.within}/{t.compared} agree, {t.unavailable} n/a"
                                                  for o, t in tallies.items()))
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    out(f"performance designs, IPM vs Clarabel: {count} seeded families (seeds {first_seed}..{first_seed + count - 1}),"
        f" tolerance {tol:g} relative; CPU {time.process_time() - start:.1f} s, load average {load}")
    out("")
    out("| objective | compared | same verdict | figure within tol | otherwise the IPM's the better | IPM not available |")
    out("|---|---|---|---|---|---|")
    for obj, t in tallies.items():
        out(f"| {obj} | {t.compared} | {t.same_verdict} | {t.within} | {t.ipm_better} | {t.unavailable} |")
    for obj, t in tallies.items():
        if t.unavailable:
            out(f"IPM not available for objective {obj}: {'; '.join(sorted(t.reasons))}")
        bad = sorted(t.worst, key=lambda w: -w[0])[:3]
        for rel, text in bad:
            if rel > tol:
                out(f"worst ({obj}): {text}" + ("" if np.isinf(rel) else f", relative {rel:.2e}"))
    return tallies


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench perf-check")
    p.add_argument("--count", type=int, default=200)
    p.add_argument("--tol", type=float, default=1e-6)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--objectives", default=",".join(OBJECTIVES), help="comma-separated subset")
    p.add_argument("--progress", action="store_true", help="one line per family")
    a = p.parse_args(argv)
    objectives = [o.strip() for o in a.objectives.split(",") if o.strip()]
    for o in objectives:
        if o not in OBJECTIVES:
            p.error(f"unknown objective {o!r}; choose from {', '.join(OBJECTIVES)}")
    tallies = run(a.count, a.tol, objectives, a.first_seed,
                  progress=(lambda line: print(line, flush=True)) if a.progress else None)
    bad = sum(t.compared - t.within - t.ipm_better for t in tallies.values())
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
