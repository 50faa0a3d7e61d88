"""Solver benchmark: per method and shape, cold and warm wall time next to Clarabel's own time.

Every (case, method) cell is measured in its own child process
(``python -m bench.solver_bench --child CASE METHOD ...``) so that

* "cold" really is the first design of that shape in a process: the child
  first runs one tiny design of another shape (imports, cvxpy's first-use
  costs), then ``problem_cache.clear()`` and times ``design()``, which builds
  and canonicalizes the cvxpy problem and solves it;
* a case that runs away is killed by the parent after a hard deadline.

Warm = the same design again with the compiled problem cached: median over
repeats.  Clarabel = the sum of Clarabel's own reported solve times over all
solves of one design (``res.timings["solver"]``), median over the same
repeats.  The hand-written baselines (:mod:`bench.handwritten`) run in the
same child, interleaved with the warm repeats, so ratios come from the same
minutes of machine load.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time

TARGET_LMI = 3.0  # warm lmi (paper example) / Clarabel
TARGET_CCL = 1.5  # ccl per iteration / Clarabel per iteration
MEM_LIMIT_GB = 6.0  # address-space cap of a child (the machine is shared: never wake the OOM killer)


def clarabel_kkt_gb(n: int, r: int, n_drop: int, method: str) -> float:
    """Rough size of the dense PSD blocks Clarabel puts in its KKT matrix (GB, one copy).

    Clarabel stores, per PSD cone of side d, a dense block of t x t doubles with
    t = d(d+1)/2.  ``lmi`` has r*n_drop cones of side 2n; ``ccl`` has r*n_drop + 1
    cones of side 2*n*n_drop.  The factorization needs at least as much again.
    """
    if method == "ccl":
        cones, d = r * n_drop + 1, 2 * n * n_drop
    else:
        cones, d = r * n_drop, 2 * n
    t = d * (d + 1) // 2
    return cones * t * t * 8 / 2**30


# ----------------------------------------------------------------------------- child side
def _tiny_warmup(method: str) -> None:
    from solver import PlantFamily, design

    design(PlantFamily(F=[[[0.5, 0.1], [0.0, 0.7]]], G=[[[1.0], [0.0]]]), 1, method=method, decay_rate=None)


def _one_design(family, n_drop, method, budget):
    """Run design(); return a dict (never raises for solver trouble)."""
    from solver import SolverFailed, design

    t0 = time.perf_counter()
    try:
        res = design(family, n_drop, method=method, time_limit=budget, decay_rate=None)  # one SDP (the tables time it)
    except SolverFailed as err:
        return {"ok": False, "wall": time.perf_counter() - t0, "outcome": f"SolverFailed({getattr(err, 'status', '')})"}
    wall = time.perf_counter() - t0
    return {
        "ok": res.outcome == "stabilized",
        "wall": wall,
        "outcome": res.outcome,
        "solver": float(res.timings.get("solver", float("nan"))),
        "solves": int(res.timings.get("solves", 0)),
        "iterations": len(res.history),
        "message": res.message,
    }


def child(case: str, method: str, repeats: int, hand_repeats: int, cold_repeats: int, budget: float,
          mem_gb: float = MEM_LIMIT_GB) -> dict:
    import resource

    cap = int(mem_gb * 2**30)
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    from solver.compiled import problem_cache

    from . import handwritten
    from .cases import CASES, shape

    desc, build, n_drop, _ = CASES[case]
    family = build()
    out = {"case": case, "desc": desc, "shape": shape(family, n_drop), "method": method, "budget": budget}
    kkt = clarabel_kkt_gb(family.n_states, family.n_modes, n_drop, method)
    if 2 * kkt > mem_gb:
        out["memory"] = (f"not run: Clarabel's KKT alone would hold ~{kkt:.0f} GB of dense PSD blocks "
                         f"(> {mem_gb:g} GB cap)")
        return out
    _tiny_warmup(method)

    colds = []
    for _ in range(max(1, cold_repeats)):
        problem_cache.clear()
        colds.append(_one_design(family, n_drop, method, budget))
        if not colds[-1]["ok"] or colds[-1]["wall"] * (cold_repeats + 1) > budget:
            break
    out["cold"] = colds
    if not colds[0]["ok"]:
        out["skipped"] = "cold design did not stabilize within the budget"
        return out

    hand_fn = handwritten.ccl_rebuild if method == "ccl" else handwritten.lmi_rebuild
    hand_kw = {"time_limit": budget} if method == "ccl" else {}
    # Keep the whole cell within about 3 budgets: fewer repeats for slow cells.
    per_design = statistics.median(c["wall"] for c in colds)
    repeats = max(1, min(repeats, int(budget / max(per_design, 1e-9))))
    hand_repeats = max(1, min(hand_repeats, int(budget / max(per_design * 2, 1e-9))))
    warm, hand = [], []
    block = max(1, repeats // hand_repeats)
    t_start = time.perf_counter()
    while len(warm) < repeats or len(hand) < hand_repeats:
        for _ in range(block):
            if len(warm) < repeats:
                warm.append(_one_design(family, n_drop, method, budget))
        if len(hand) < hand_repeats:
            h = hand_fn(family, n_drop, **hand_kw)
            hand.append({"wall": h.wall, "solver": h.solver_time, "iterations": h.iterations,
                         "outcome": h.outcome, "message": h.message})
        if time.perf_counter() - t_start > 3 * budget:
            out["truncated"] = f"stopped after {len(warm)} warm / {len(hand)} hand-written runs (3x budget)"
            break
    out["warm"] = warm
    out["hand"] = hand
    return out


# ----------------------------------------------------------------------------- parent side
def run_cell(case, method, repeats, hand_repeats, cold_repeats, budget, mem_gb=MEM_LIMIT_GB,
             python=sys.executable) -> dict:
    cmd = [python, "-m", "bench.solver_bench", "--child", case, method,
           str(repeats), str(hand_repeats), str(cold_repeats), str(budget), str(mem_gb)]
    deadline = 5 * budget + 120
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=deadline, cwd=os.getcwd())
    except subprocess.TimeoutExpired:
        return {"case": case, "method": method, "killed": f"killed after {time.perf_counter() - t0:.0f} s"}
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        return {"case": case, "method": method, "error": f"child exit {proc.returncode}: {tail[0][:160]}"}
    return json.loads(lines[-1])


def _med(rows, key):
    vals = [r[key] for r in rows if key in r and r[key] == r[key]]
    return statistics.median(vals) if vals else float("nan")


def fmt_t(seconds: float) -> str:
    if seconds != seconds:
        return "-"
    if seconds < 1.0:
        return f"{seconds * 1e3:.2f} ms" if seconds < 0.01 else f"{seconds * 1e3:.1f} ms"
    return f"{seconds:.2f} s"


def summarize(cell: dict) -> dict:
    """Numbers of one cell; every ratio is between numbers of the same child process."""
    s = {"case": cell.get("case"), "method": cell.get("method"), "shape": cell.get("shape", ""),
         "desc": cell.get("desc", cell.get("case"))}
    if "killed" in cell or "error" in cell or "memory" in cell:
        s["note"] = cell.get("killed") or cell.get("error") or cell.get("memory")
        return s
    colds = cell["cold"]
    s["cold"] = _med(colds, "wall")
    s["cold_n"] = len(colds)
    if "skipped" in cell:
        c = colds[0]
        s["note"] = (f"> {cell['budget']:g} s, not run: first design ended '{c['outcome']}' after "
                     f"{c['wall']:.0f} s" + (f" ({c['iterations']} solves of the CCL SDP)" if "iterations" in c else ""))
        return s
    warm = cell["warm"]
    s["outcome"] = warm[0]["outcome"]
    s["warm"] = _med(warm, "wall")
    s["warm_n"] = len(warm)
    s["clarabel"] = _med(warm, "solver")
    s["solves"] = _med(warm, "solves")
    s["iterations"] = _med(warm, "iterations")
    s["ratio"] = s["warm"] / s["clarabel"]
    hand = cell["hand"]
    s["hand"] = _med(hand, "wall")
    s["hand_n"] = len(hand)
    s["hand_clarabel"] = _med(hand, "solver")
    s["hand_iters"] = _med(hand, "iterations")
    s["hand_outcome"] = hand[0]["outcome"]
    s["hand_ratio"] = s["hand"] / s["warm"]
    if "truncated" in cell:
        s["note"] = cell["truncated"]
    return s


HEADER = ("| case | shape | method | outcome | CCL iters (solves) | cold | warm (median) | Clarabel | warm/Clarabel "
          "| warm/iter | Clarabel/iter | hand-written rebuild | its Clarabel | its iters | rebuild/warm | runs c/w/h |")


def table(summaries) -> str:
    lines = [HEADER, "|" + "---|" * (HEADER.count("|") - 1)]
    for s in summaries:
        if "warm" not in s:
            lines.append(f"| {s['case']} | {s['shape']} | {s['method']} | - | - | "
                         f"{fmt_t(s.get('cold', float('nan')))} | {s.get('note', '')} | | | | | | | | | |")
            continue
        iters = s["iterations"] - 1 if s["method"] == "ccl" else None  # history[0] is Step 1
        per = s["iterations"] if s["method"] == "ccl" else None
        it_col = f"{iters:g} ({s['solves']:g})" if iters is not None else f"- ({s['solves']:g})"
        per_w = fmt_t(s["warm"] / per) if per else "-"
        per_c = fmt_t(s["clarabel"] / per) if per else "-"
        hand_it = f"{s['hand_iters'] - 1:g}" if s["method"] == "ccl" else "-"
        outcome = s["outcome"]
        if s["hand_outcome"] != outcome:
            outcome += f" (hand-written: {s['hand_outcome']})"
        lines.append(
            f"| {s['case']} | {s['shape']} | {s['method']} | {outcome} | {it_col} | {fmt_t(s['cold'])} "
            f"| {fmt_t(s['warm'])} | {fmt_t(s['clarabel'])} | {s['ratio']:.2f}x | {per_w} | {per_c} "
            f"| {fmt_t(s['hand'])} | {fmt_t(s['hand_clarabel'])} | {hand_it} | {s['hand_ratio']:.1f}x "
            f"| {s['cold_n']}/{s['warm_n']}/{s['hand_n']} |"
        )
    return "\n".join(lines)


def targets(summaries) -> list[str]:
    out = []
    for s in summaries:
        if s["case"] == "paper" and s["method"] == "lmi" and "warm" in s:
            ok = s["ratio"] <= TARGET_LMI
            out.append(f"{'PASS' if ok else 'MISS'}  warm lmi, paper example: {fmt_t(s['warm'])} vs Clarabel "
                       f"{fmt_t(s['clarabel'])} = {s['ratio']:.2f}x (target <= {TARGET_LMI:g}x)")
    for s in summaries:
        if s["method"] == "ccl":
            if "warm" in s:
                ok = s["ratio"] <= TARGET_CCL
                per = s["iterations"]
                out.append(f"{'PASS' if ok else 'MISS'}  ccl per iteration, {s['case']}: {fmt_t(s['warm'] / per)} vs "
                           f"Clarabel {fmt_t(s['clarabel'] / per)} = {s['ratio']:.2f}x (target <= {TARGET_CCL:g}x)")
            else:
                out.append(f"n/a   ccl per iteration, {s['case']}: {s.get('note', 'not measured')}")
    return out


def main_table(cases, repeats, hand_repeats, cold_repeats, budget, lmi_budget, paper_repeats,
               mem_gb=MEM_LIMIT_GB, echo=print):
    from .cases import CASES

    summaries = []
    for case in cases:
        for method in CASES[case][3]:
            reps = paper_repeats if (case == "paper" and method == "lmi") else repeats
            b = budget if method == "ccl" else lmi_budget
            t0 = time.perf_counter()
            cell = run_cell(case, method, reps, hand_repeats, cold_repeats, b, mem_gb)
            s = summarize(cell)
            echo(f"  measured {case}/{method} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
            summaries.append(s)
    return summaries


if __name__ == "__main__":
    if len(sys.argv) == 9 and sys.argv[1] == "--child":
        _, _, case, method, rep, hrep, crep, budget, mem = sys.argv
        result = child(case, method, int(rep), int(hrep), int(crep), float(budget), float(mem))
        print(json.dumps(result))
    else:
        print("run `python -m bench` instead", file=sys.stderr)
        sys.exit(2)
