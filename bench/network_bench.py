"""``python -m bench network``: design and analysis time on networks against automaton nodes and n.

Each cell is one ``design(family, network=net, decay_rate=None)`` (``solver="AUTO"``: the structured IPM, Clarabel as
its fallback) and one ``analyze(family, gains, network=net)`` of the designed gains, in this process.  ``--solvers``
prints the IPM beside Clarabel instead: per cell and solver, in a fresh spawned process each, the network LMI alone
(``network_lmi.solve_sdp``: its t*, CPU seconds and the process's peak resident-set growth, ``ru_maxrss``) and the whole
``design(..., solver=...)`` (CPU seconds, outcome, solves; its analysis re-check runs on Clarabel either way).
Families: the paper's motor (n = 2, r = 3, bench/../tests/solver/paper_data.py) and seeded random stable-ish
families of n states, one input, one plant mode.  Reported: network, nodes, the design's form (lifted / augmented)
and its estimated size (``design_size``: transitions x plant modes, LMI size), outcome and the method that
certified (``network_lmi`` convex, ``network_ccl`` cone complementarity), wall and CPU seconds of the design and
of the analysis, and the load average.  Bounded drops is timed both ways: ``design(fam, n_drop)`` and
``design(fam, network=Network.bounded_drops(n_drop))`` (the same code path; the ratio is the overhead).

``--analysis``: the analysis of the designed gains on the IPM (block-sparse Schur complement) beside Clarabel
(:func:`analysis_table`), over bounded_drops(3), delays(1, 3), delays(2, 3), weakly_hard(2, 5, 3), (3, 8, 4), (4, 10, 5)
and n = 2, 4, 8.

``--brackets``: how far the cost and l2-gain brackets close on badly scaled families (:func:`brackets_table`): random
3-state families (``bench.cases.random_family(3, 2, 1, seed)``, seeds 0-5) in coordinates whose state scales are drawn
from 1e-3 to 1e3, on delays(1, 2) and weakly_hard(1, 3, 2), the trace cost and the l2 gain from ``E = G_1``.

    python -m bench network [--quick] [--largest] [--time-limit 120] [--overhead-only] [--solvers] [--analysis]
                            [--brackets]
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np


def _load() -> str:
    return f"{os.getloadavg()[0]:.1f}"


def _family(n: int, seed: int):
    from solver import PlantFamily

    rng = np.random.default_rng(seed)
    F = rng.normal(size=(n, n))
    F = 1.1 * F / max(abs(np.linalg.eigvals(F)))  # mildly unstable
    G = rng.normal(size=(n, 1))
    return PlantFamily([F], [G])


def _paper():
    from solver import PlantFamily

    F = [[[0.6703, -0.0018], [0.0294, 0.5134]], [[0.6703, -0.0015], [0.0378, 0.3678]],
         [[0.6702, -0.0010], [0.0502, 0.1353]]]
    G = [[[0.1648], [0.0035]], [[0.1648], [0.0048]], [[0.1648], [0.0073]]]
    return PlantFamily(F, G, sampling_period=0.1)


def cell(name, fam, net, time_limit):
    from solver import analyze, design
    from solver.compiled import design_size
    from solver.errors import InvalidInput

    size = design_size("lmi", fam.n_states, fam.n_inputs, fam.n_modes, net.n_drop, network=net)
    row = {"family": name, "n": fam.n_states, "r": fam.n_modes, "network": net.describe(), "nodes": net.nodes,
           "size": f"{size.n_modes} x {size.state_size or 2 * fam.n_states}", "load": _load()}
    w0, c0 = time.perf_counter(), time.process_time()
    try:
        res = design(fam, network=net, decay_rate=None, time_limit=time_limit)
    except InvalidInput as err:
        row["outcome"] = f"refused: {str(err)[:60]}"
        return row
    row.update(outcome=res.outcome, method=res.method, design_wall=time.perf_counter() - w0,
               design_cpu=time.process_time() - c0)
    if res.gains is not None and res.outcome == "stabilized":
        w0, c0 = time.perf_counter(), time.process_time()
        rep = analyze(fam, res.gains, network=net)
        row.update(analysis_wall=time.perf_counter() - w0, analysis_cpu=time.process_time() - c0,
                   analysis=str(rep.stable))
    return row


def _one_solver(args):
    """In a fresh process: the network LMI alone and the whole design on one solver (CPU s, peak RSS growth)."""
    import resource

    from solver import design
    from solver.methods import network_lmi

    fam, net, solver, time_limit = args
    prob = network_lmi.build_problem(fam, net)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    c0 = time.process_time()
    try:
        sol = network_lmi.solve_sdp(prob, np.ones(prob.n_blocks), time_limit, solver=solver)
        out = {"t": sol.t, "iterations": sol.iterations}
    except Exception as err:  # noqa: BLE001 - a benchmark row, not a verdict
        out = {"t": float("nan"), "error": str(err)[:40]}
    out["sdp_cpu"] = time.process_time() - c0
    out["sdp_mb"] = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) / 1024
    c0 = time.process_time()
    res = design(fam, network=net, decay_rate=None, solver=solver, time_limit=time_limit)
    out.update(design_cpu=time.process_time() - c0, outcome=res.outcome, method=res.method, solver=res.solver,
               solves=res.solve_count)
    return out


def solver_cell(name, fam, net, time_limit):
    """One row of the ``--solvers`` table: the IPM and Clarabel, each in a fresh spawned process."""
    from solver.methods import network_lmi

    prob = network_lmi.build_problem(fam, net)
    row = {"family": name, "network": net.describe(), "nodes": net.nodes, "form": prob.form,
           "size": f"{prob.n_blocks} x {2 * prob.k}", "load": _load()}
    for solver in ("IPM", "CLARABEL"):
        row[solver] = _spawned(_one_solver, (fam, net, solver, time_limit))
    return row


def solver_table(cases, time_limit) -> None:
    print("| family | network | nodes | form | blocks x side | t* IPM / Clarabel | LMI CPU s IPM / Clarabel | "
          "LMI peak MB IPM / Clarabel | design CPU s IPM / Clarabel | outcome (solves) IPM / Clarabel | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, fam, net in cases:
        row = solver_cell(name, fam, net, time_limit)
        a, b = row["IPM"], row["CLARABEL"]
        print(f"| {row['family']} | {row['network']} | {row['nodes']} | {row['form']} | {row['size']} | "
              f"{a['t']:.6g} / {b['t']:.6g} | {a['sdp_cpu']:.3f} / {b['sdp_cpu']:.3f} | "
              f"{a['sdp_mb']:.0f} / {b['sdp_mb']:.0f} | {a['design_cpu']:.2f} / {b['design_cpu']:.2f} | "
              f"{a['outcome']} ({a['solves']}, {a['solver']}) / {b['outcome']} ({b['solves']}) | {row['load']} |",
              flush=True)


def _one_analysis(args):
    """In a fresh process: ``analyze(network=)`` of given gains on one solver (CPU s, the process's peak RSS in MB,
    imports included)."""
    import resource

    from solver import analyze

    fam, net, gains, solver, bounds = args
    base = 0
    c0 = time.process_time()
    try:
        rep = analyze(fam, gains, network=net, solver=solver, bounds=bounds)
        out = {"stable": rep.stable, "upper": rep.jsr_upper_bound}
    except Exception as err:  # noqa: BLE001 - a benchmark row, not a verdict
        out = {"stable": f"error: {str(err)[:30]}", "upper": None}
    out["cpu"] = time.process_time() - c0
    out["mb"] = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) / 1024
    return out


def _spawned(fn, args):
    """``fn(args)`` in a fresh spawned process (a forked pool worker deadlocked on a lock the parent held)."""
    import multiprocessing as mp

    with mp.get_context("spawn").Pool(1) as pool:
        return pool.apply(fn, (args,))


def analysis_table(cases, time_limit, clarabel_bounds_up_to: int = 2000) -> None:
    """``--analysis``: per case, the design (``solver="AUTO"``) and the analysis of its gains on the IPM and Clarabel.

    Node SDP: ``analyze(..., bounds="none")`` (the verdict's solve at rate 1 and the cycle search), CPU s and the
    process's peak RSS, ``solver="IPM"`` / ``"CLARABEL"``; full: with the CJSR bisection (``"AUTO"`` / ``"CLARABEL"``; Clarabel's
    only up to ``clarabel_bounds_up_to`` node-SDP rows, states x D, beyond which it takes many minutes).
    """
    from solver import design
    from solver.network_analysis import product_automaton

    print("| family | network | states x D | design CPU s (AUTO) | node SDP CPU s IPM / Clarabel | "
          "node SDP peak MB IPM / Clarabel | full analysis CPU s AUTO / Clarabel | CJSR upper AUTO / Clarabel | "
          "verdict | load |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, fam, net in cases:
        D = fam.n_states * net.n_drop
        V = product_automaton(net, fam.n_modes, "per_interval").size
        c0 = time.process_time()
        res = design(fam, network=net, decay_rate=None, time_limit=time_limit)
        design_cpu = time.process_time() - c0
        head = f"| {name} | {net.describe()} | {V} x {D} | {design_cpu:.2f} ({res.outcome}) |"
        if res.gains is None:
            print(head + " - | - | - | - | - | " + _load() + " |", flush=True)
            continue
        a = _spawned(_one_analysis, (fam, net, res.gains, "IPM", "none"))
        b = _spawned(_one_analysis, (fam, net, res.gains, "CLARABEL", "none"))
        fa = _spawned(_one_analysis, (fam, net, res.gains, "AUTO", "quadratic"))
        fb = (_spawned(_one_analysis, (fam, net, res.gains, "CLARABEL", "quadratic")) if V * D <= clarabel_bounds_up_to
              else {"cpu": float("nan"), "upper": None})

        def up(x):
            return "-" if x["upper"] is None else f"{x['upper']:.4f}"

        print(head + f" {a['cpu']:.2f} / {b['cpu']:.2f} | {a['mb']:.0f} / {b['mb']:.0f} | {fa['cpu']:.2f} / "
              f"{fb['cpu']:.2f} | {up(fa)} / {up(fb)} | {a['stable']} / {b['stable']} | {_load()} |", flush=True)


def bounded_drops_overhead(repeats: int = 15) -> list[str]:
    """Best and median wall time of today's design and of the same through ``network=bounded_drops``.

    Interleaved calls; on a loaded machine the best of many is the figure to compare (the median moves with load).
    """
    from solver import Network, design

    fam = _paper()
    out = []
    for kwargs, label in (({"decay_rate": None}, "decay_rate=None"), ({}, 'decay_rate="auto"')):
        design(fam, 3, **kwargs), design(fam, network=Network.bounded_drops(3), **kwargs)
        a, b = [], []
        for _ in range(repeats):
            t = time.perf_counter()
            design(fam, 3, **kwargs)
            a.append(time.perf_counter() - t)
            t = time.perf_counter()
            design(fam, network=Network.bounded_drops(3), **kwargs)
            b.append(time.perf_counter() - t)
        out.append(f"| paper, n_drop = 3, {label} | {1e3 * min(a):.2f} ({1e3 * np.median(a):.1f}) ms | "
                   f"{1e3 * min(b):.2f} ({1e3 * np.median(b):.1f}) ms | {min(b) / min(a):.2f} |")
    return out


def badly_scaled(fam, seed: int):
    """The family in coordinates ``x = T x~``, state scales drawn from 1e-3 to 1e3 (generator seed ``100 + seed``;
    inputs unscaled)."""
    from solver import PlantFamily

    t = np.exp(np.random.default_rng(100 + seed).uniform(np.log(1e-3), np.log(1e3), fam.n_states))
    return PlantFamily(F=np.asarray(fam.F) / t[None, :, None] * t[None, None, :], G=np.asarray(fam.G) / t[None, :, None])


def brackets_table(seeds=range(6)) -> None:
    """Upper / lower end of each network bracket (one design per cell, in this process), the bound's memory (0: node
    matrices, L: one matrix per sequence of the last L transitions) and the CPU; a line of counts per row."""
    from solver import Network, design

    from .cases import random_family

    print("| network | objective | upper / lower (memory) per seed | within 1 % / 5 % | widest | CPU s |")
    print("|---|---|---|---|---|---|")
    for net in (Network.delays(1, 2), Network.weakly_hard(1, 3, 2)):
        for objective in ("cost", "hinf"):
            cells, ratios, cpu = [], [], 0.0
            for seed in seeds:
                fam = badly_scaled(random_family(3, 2, 1, seed=seed), seed)
                extra = {} if objective == "cost" else {"disturbance": np.asarray(fam.G[0])}
                start = time.process_time()
                res = design(fam, network=net, objective=objective, **extra)
                cpu += time.process_time() - start
                perf = res.performance
                if res.outcome != "stabilized" or perf is None or not perf.lower:
                    cells.append(res.outcome)
                    continue
                ratios.append(perf.upper / perf.lower)
                cells.append(f"{ratios[-1]:.3f} ({perf.memory})")
            close = sum(r <= 1.01 for r in ratios), sum(r <= 1.05 for r in ratios)
            widest = f"{max(ratios):.3f}" if ratios else "-"
            print(f"| {net.describe()} | {objective} | {', '.join(cells)} | {close[0]} / {close[1]} of {len(ratios)} | "
                  f"{widest} | {cpu:.1f} |", flush=True)


def main(argv=None) -> int:
    """Print the networks table, then the bounded-drops overhead (``--overhead-only``: just that)."""
    from solver import Network

    ap = argparse.ArgumentParser(prog="python -m bench network")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--time-limit", type=float, default=120.0)
    ap.add_argument("--overhead-only", action="store_true")
    ap.add_argument("--solvers", action="store_true", help="the IPM beside Clarabel (the network LMI and design())")
    ap.add_argument("--analysis", action="store_true",
                    help="analyze(network=) on the IPM beside Clarabel, against states and n (docs/performance.md)")
    ap.add_argument("--brackets", action="store_true",
                    help="how far the cost and l2-gain brackets close on badly scaled families (docs/performance.md)")
    ap.add_argument("--largest", action="store_true",
                    help="also weakly_hard(4, 10, 5) at n = 2 (256 nodes) and delays(3, 5) at n = 4 (~15 min)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    if args.brackets:
        brackets_table(range(2) if args.quick else range(6))
        return 0
    if args.overhead_only:
        for line in bounded_drops_overhead(40):
            print(line, flush=True)
        return 0
    cases = [("paper", _paper(), Network.weakly_hard(2, 5, 3)), ("paper", _paper(), Network.delays(1, 3))]
    sizes = (2, 4) if args.quick else (2, 4, 6, 8)
    for n in sizes:
        fam = _family(n, n)
        cases += [(f"random n={n}", fam, Network.weakly_hard(2, 5, 3)),
                  (f"random n={n}", fam, Network.weakly_hard(3, 8, 4)),
                  (f"random n={n}", fam, Network.delays(1, 2)),
                  (f"random n={n}", fam, Network.delays(2, 3))]
    if args.largest:
        cases += [("random n=2", _family(2, 2), Network.weakly_hard(4, 10, 5)),
                  ("random n=4", _family(4, 4), Network.delays(3, 5))]
    if args.analysis:
        cases = []
        for n in (2, 4) if args.quick else (2, 4, 8):
            fam = _family(n, n)
            nets = [Network.bounded_drops(3), Network.delays(1, 3), Network.delays(2, 3), Network.weakly_hard(2, 5, 3),
                    Network.weakly_hard(3, 8, 4)] + ([Network.weakly_hard(4, 10, 5)] if n < 8 else [])
            cases += [(f"random n={n}", fam, net) for net in nets]
        analysis_table(cases, args.time_limit)
        return 0
    if args.solvers:
        solver_table(cases, args.time_limit)
        return 0
    print("| family | network | nodes | transitions x state | outcome (method) | design wall [CPU] s | "
          "analysis wall [CPU] s | load |")
    print("|---|---|---|---|---|---|---|---|")
    for name, fam, net in cases:
        row = cell(name, fam, net, args.time_limit)
        design_t = (f"{row['design_wall']:.2f} [{row['design_cpu']:.2f}]" if "design_wall" in row else "-")
        analysis_t = (f"{row['analysis_wall']:.2f} [{row['analysis_cpu']:.2f}]" if "analysis_wall" in row else "-")
        method = f" ({row['method']})" if "method" in row else ""
        print(f"| {row['family']} | {row['network']} | {row['nodes']} | {row['size']} | {row['outcome']}{method} | "
              f"{design_t} | {analysis_t} | {row['load']} |", flush=True)
    print()
    print("| bounded drops | design(fam, n_drop): best (median) | design(fam, network=bounded_drops(3)) | "
          "ratio of the best |")
    print("|---|---|---|---|")
    for line in bounded_drops_overhead(10 if args.quick else 40):
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
