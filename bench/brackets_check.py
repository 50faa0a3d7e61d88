"""``python -m bench brackets [--count N]``: how far the performance brackets close, before/after the deeper search.

Every seeded family of :func:`bench.ipm_check.draw_family` (kinds near, independent, badly scaled, zero input,
repeated modes, near the stabilizability boundary, huge/tiny entries; n 2..4 and at most 48 lifted LMI rows
here) is designed for each objective of :data:`OBJECTIVES` (``design(...)``, default solver).  On the design's
gains and certificate, in the user's coordinates, the witnessed lower end is computed twice in one run:
"before", the periodic patterns and (cost) the two-run search (:func:`solver.brackets.lower_bound` without the
certificate, hinf without the pattern growth), and "after", with the prefix search (cost, given the certificate)
and the pattern growth and charge-then-release witnesses (hinf; docs/design.md §8.4).  The certified
upper end is the design's (for the cost the smaller of the quadratic certificate's bound and the prefix tree's
certified bound, docs/design.md §8.4, "Tree bound"; the quadratic one is printed too).  Prints the distribution of
``gap = (upper - lower) / upper`` for both, per objective and in all, the CPU time of each search, and the CTMS
two-mode pendulum (n_drop = 3, weights I and the CTMS Q).  For the cost, ``(quadratic - upper) / quadratic`` is
the part of the quadratic certificate's slack the tree bound removed.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

OBJECTIVES = ("cost", "cost (x0)", "hinf", "u_max + cost")
THRESHOLDS = (1e-6, 1e-3, 1e-2, 5e-2)


def request(objective: str, fam, rng) -> dict:
    n, m = fam.n_states, fam.n_inputs
    if objective == "cost":
        return {"objective": "cost"}
    if objective == "cost (x0)":
        return {"objective": "cost", "x0": rng.standard_normal(n)}
    if objective == "hinf":
        return {"objective": "hinf", "disturbance": list(fam.G) if np.any(fam.G) else [np.eye(n)[:, :1]] * fam.n_modes}
    return {"objective": "cost", "x0": rng.standard_normal(n), "u_max": 10.0 ** rng.uniform(0.5, 1.5, m)}


def brackets_of(fam, N, objective, kw, budget=None):
    """``(upper, lower before, lower after, bound, cpu before, cpu after, quadratic upper)`` of one design, or
    None (``upper`` the design's certified upper end; the quadratic certificate's own bound last)."""
    from solver import design
    from solver.brackets import GROW_ABOVE_GAP, NODE_BUDGET, lower_bound
    from solver.methods import performance
    from solver.network import ModeSet
    from solver.transients import transient_witness

    res = design(fam, N, **kw)
    perf = res.performance
    if res.gains is None or perf is None or perf.upper is None or not perf.verified:
        return None
    kind = perf.kind
    lifted, x0, _ = performance.prepare(ModeSet.from_family(fam, N), "lmi", kw["objective"], kw.get("weights"), kw.get("x0"),
                                        kw.get("disturbance"), None, kw.get("u_max"), None)
    gains = np.asarray(res.gains, dtype=float)
    stop = getattr(perf, "certificate_upper", perf.upper)  # the bracket's own searches stop at the quadratic bound
    t0 = time.process_time()
    before = lower_bound(lifted, gains, kind, x0, stop=stop, deep=kind == "cost")  # main's: no growth
    t1 = time.process_time()
    after = lower_bound(lifted, gains, kind, x0, stop=stop, certificate=perf.certificate,
                        budget=NODE_BUDGET if budget is None else budget)
    lower = after.value
    if kind == "hinf" and lower is not None and np.isfinite(lower) and 0 < lower * (1 + GROW_ABOVE_GAP) < perf.upper:
        # as the bracket does (docs/design.md §8.4, "Transient witness")
        found = transient_witness(lifted.numeric(gains), lower)
        lower = lower if found is None else found.value
    t2 = time.process_time()
    return (perf.upper, before.value, lower, after.bound, t1 - t0, t2 - t1,
            getattr(perf, "certificate_upper", perf.upper))


def _gap(upper, lower):
    if lower is None or not np.isfinite(lower):
        return np.inf
    return max((upper - lower) / upper, 0.0)


def table(rows: dict, out=print) -> None:
    out("| objective | brackets | gap <= 1e-6 | <= 0.1 % | <= 1 % | <= 5 % | median gap | worst gap | "
        "CPU per bracket (s) |")
    out("|---|---|---|---|---|---|---|---|---|")
    for name, items in rows.items():
        if not items:
            continue
        for which, col, cpu in (("before", 1, 4), ("after", 2, 5)):
            gaps = np.array([_gap(r[0], r[col]) for r in items])
            cells = [f"{np.mean(gaps <= t) * 100:.0f} %" for t in THRESHOLDS]
            out(f"| {name}, {which} | {len(items)} | {' | '.join(cells)} | {np.median(gaps):.2e} | "
                f"{np.max(gaps):.2e} | {np.mean([r[cpu] for r in items]):.3f} |")


def run(count: int, first_seed: int = 0, out=print, budget=None, save: str | None = None,
        merge: list | None = None, hinf_every: int = 1) -> dict:
    """Design and bracket ``count`` families (``save``: their rows as JSON); ``merge``: print the tables of
    saved runs instead (several processes on disjoint seeds)."""
    from bench.ipm_check import draw_family

    rows = {obj: [] for obj in OBJECTIVES}
    kinds: dict = {}
    start = time.process_time()
    if merge:
        for name in merge:
            with open(name) as fh:
                saved = json.load(fh)
            for obj in OBJECTIVES:
                rows[obj] += [tuple(r) for r in saved["rows"][obj]]
            for kind, items in saved["kinds"].items():
                kinds.setdefault(kind, []).extend(tuple(r) for r in items)
        count = sum(json.load(open(name))["count"] for name in merge)
    for seed in range(first_seed, first_seed + (0 if merge else count)):
        fam, N, desc = draw_family(seed, max_n=4, max_lmi_rows=48)
        rng = np.random.default_rng(20_000 + seed)
        for obj in OBJECTIVES:
            kw = request(obj, fam, rng)
            if obj == "hinf" and seed % hinf_every:  # the exhaustive hinf search is the costly one
                continue
            try:
                got = brackets_of(fam, N, obj, kw, budget)
            except Exception as err:  # noqa: BLE001  (a design that raises is a bug to see)
                out(f"seed {seed} {obj}: {type(err).__name__}: {err}"[:200])
                continue
            if got is not None:
                rows[obj].append(got)
                kinds.setdefault(desc.split()[0], []).append(got)
    if save:
        with open(save, "w") as fh:
            json.dump({"count": count, "rows": rows, "kinds": kinds}, fh)
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    out(f"brackets: {count} seeded families (seeds {first_seed}..{first_seed + count - 1}, n 2..4, <= 48 LMI rows), "
        f"objectives {', '.join(OBJECTIVES)}; CPU {time.process_time() - start:.1f} s, load average {load}")
    out("")
    everything = [r for items in rows.values() for r in items]
    table({**rows, "all": everything}, out)
    out("")
    out("per family kind (all objectives):")
    out("")
    table(dict(sorted(kinds.items())), out)
    cost = [r for obj in ("cost", "cost (x0)", "u_max + cost") for r in rows[obj] if r[3] is not None]
    if cost:
        slack = np.array([max((r[0] - r[3]) / r[0], 0.0) for r in cost])
        left = np.array([max((r[3] - r[2]) / r[0], 0.0) for r in cost])
        out("")
        closed = np.array([max((r[-1] - r[0]) / r[-1], 0.0) for r in cost])
        out(f"cost brackets ({len(cost)}): (upper - search bound) / upper: median "
            f"{np.median(slack):.2e}, 90th percentile {np.quantile(slack, 0.9):.2e}, worst {np.max(slack):.2e}; "
            f"what a deeper search could still add (bound - lower) / upper: median {np.median(left):.2e}, "
            f"worst {np.max(left):.2e}; the quadratic certificate's slack the tree bound removed "
            f"(quadratic - upper) / quadratic: median {np.median(closed):.2e}, 90th percentile "
            f"{np.quantile(closed, 0.9):.2e}, worst {np.max(closed):.2e}")
    return rows


def pendulum(out=print) -> None:
    from tests.solver.plants import PENDULUM_Q, pendulum as family

    fam = family((0.2, 0.3))
    for name, (Q, R) in (("Q = I", (np.eye(4), np.eye(1))), ("CTMS Q", (PENDULUM_Q, np.eye(1)))):
        got = brackets_of(fam, 3, "cost", {"objective": "cost", "weights": (Q, R)})
        if got is None:
            out(f"| pendulum, {name} | no certified bracket | | | |")
            continue
        upper, lo0, lo1, bound, c0, c1, quadratic = got
        bound = float("nan") if bound is None else bound
        out(f"| pendulum (0.2, 0.3 kg), n_drop 3, {name} | {quadratic:.6g} | {upper:.6g} | "
            f"{lo0:.6g} ({_gap(upper, lo0) * 100:.2f} %) | {lo1:.6g} ({_gap(upper, lo1) * 100:.2f} %) | {bound:.6g} | "
            f"{c0:.2f} / {c1:.2f} |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench brackets")
    p.add_argument("--count", type=int, default=100)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--budget", type=int, default=None, help="prefix-search nodes (default NODE_BUDGET)")
    p.add_argument("--no-pendulum", action="store_true")
    p.add_argument("--hinf-every", type=int, default=1, help="hinf on every k-th seed only")
    p.add_argument("--save", default=None, help="write the rows as JSON (to --merge them later)")
    p.add_argument("--merge", nargs="*", default=None, help="print the tables of saved runs")
    args = p.parse_args(argv)
    out = print
    if not args.no_pendulum and not args.merge:
        out("| case | quadratic bound | upper | lower before (gap) | lower after (gap) | search bound | "
            "CPU before / after (s) |")
        out("|---|---|---|---|---|---|---|")
        pendulum(out)
        out("")
    run(args.count, args.first_seed, out, args.budget, args.save, args.merge, args.hinf_every)
    return 0
