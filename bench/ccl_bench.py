"""``python -m bench ccl``: the paper's CCL design, structured IPM (``solver="IPM"``) vs Clarabel.

Each cell is one full ``design(..., method="ccl")`` in a fresh process under an
address-space cap (``--mem-limit``), Clarabel with a wall-time budget (a cell that
runs out prints ``> X s``).  Reported: outcome, CCL iterations (Step 2 iterates;
``history[0]`` is Step 1), wall and CPU time, mean solver time per CCL SDP, peak
RSS (``ru_maxrss``) and the load average before and after each cell.

Cases (bench/cases.py): ``n4`` (random n=4, r=3, m=2, n_drop=6) and ``n8``
(random n=8, r=4, m=2, n_drop=8).  Clarabel refuses n8 before solving
(``check_memory``: its KKT system would need far more than the 4 GiB cap).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time


def child(case: str, solver: str, budget: float) -> dict:
    import resource

    from solver import design
    from solver.network import ModeSet

    from .cases import CASES

    _, make, n_drop, _ = CASES[case]
    fam = make()
    modes = ModeSet.from_family(fam, n_drop)
    out = {"case": case, "solver": solver, "modes": modes.n_modes, "side": 2 * modes.n_states * n_drop}
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        res = design(fam, n_drop=n_drop, method="ccl", solver=solver, time_limit=budget, max_iter=30)
    except Exception as exc:  # noqa: BLE001 -- reported in the table
        out["note"] = f"{type(exc).__name__}: {str(exc)[:90]}"
        if "user_limit" in str(exc) or "time_limit" in str(exc):
            out["note"] = f"> {budget:g} s (time limit, {time.perf_counter() - t0:.0f} s wall)"
        return out
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    solves = [r.solve_time for r in res.history]
    out.update(outcome=res.outcome, iterations=len(res.history) - 1, wall=wall, cpu=cpu,
               per_sdp=sum(solves) / max(len(solves), 1),
               peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
               certified=bool(res.certificate is not None and res.certificate.verified))
    return out


def _load() -> str:
    with open("/proc/loadavg") as fh:
        return " ".join(fh.read().split()[:3])


def run_cell(case: str, solver: str, budget: float, mem_gb: float) -> dict:
    cmd = [sys.executable, "-c",
           "import json, resource; from bench.ccl_bench import child; "
           f"cap = int({mem_gb} * 2**30); resource.setrlimit(resource.RLIMIT_AS, (cap, cap)); "
           f"print(json.dumps(child({case!r}, {solver!r}, {budget})))"]
    load0 = _load()
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=budget + 120, cwd=os.getcwd())
    except subprocess.TimeoutExpired:
        return {"case": case, "solver": solver, "note": f"> {budget:g} s", "load": f"{load0} / {_load()}"}
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        out = {"case": case, "solver": solver, "note": f"failed after {time.perf_counter() - t0:.0f} s: {tail[0][:90]}"}
    else:
        out = json.loads(lines[-1])
    out["load"] = f"{load0} / {_load()}"
    if "note" not in out and out.get("outcome") == "not_converged" and out["wall"] >= budget:
        out["note"] = f"> {budget:g} s ({out['iterations']} CCL iterations done)"
    return out


def table(rows) -> str:
    head = ("case", "solver", "outcome", "CCL it.", "wall", "CPU", "per SDP", "peak RSS", "load before / after")
    lines = [" | ".join(head), " | ".join("---" for _ in head)]
    for r in rows:
        if "outcome" not in r or r.get("note", "").startswith(">"):
            lines.append(" | ".join([r["case"], r["solver"], r.get("note", "?"), "-", "-", "-", "-", "-",
                                     r.get("load", "-")]))
            continue
        lines.append(" | ".join([r["case"], r["solver"], r["outcome"] + (" (certified)" if r["certified"] else ""),
                                 str(r["iterations"]), f"{r['wall']:.1f} s", f"{r['cpu']:.1f} s",
                                 f"{r['per_sdp']:.2f} s", f"{r['peak_mb']:.0f} MB", r["load"]]))
    return "\n".join(lines)


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m bench ccl")
    p.add_argument("--cases", default="n4,n8")
    p.add_argument("--solvers", default="IPM,CLARABEL")
    p.add_argument("--clarabel-cap", type=float, default=150.0, help="seconds per Clarabel cell")
    p.add_argument("--ipm-cap", type=float, default=1800.0, help="seconds per IPM cell")
    p.add_argument("--mem-limit", type=float, default=6.0, help="address-space cap per cell, GB")
    a = p.parse_args(argv)
    print(f"CCL benchmark: {os.cpu_count()} cpus, load average {_load()} at start", flush=True)
    rows = []
    for case in [c for c in a.cases.split(",") if c]:
        for solver in [s for s in a.solvers.split(",") if s]:
            cap = a.ipm_cap if solver == "IPM" else a.clarabel_cap
            row = run_cell(case, solver, cap, a.mem_limit)
            print(json.dumps(row), flush=True)
            rows.append(row)
    print()
    print(table(rows))
    print(f"\n(load average {_load()} at the end)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
