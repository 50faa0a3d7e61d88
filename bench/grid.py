"""Growth grid: how the ``lmi`` design's cost grows with n, r and n_drop.

Each cell is a seeded random family (:func:`bench.cases.random_family`,
m = 1); the SDP is the same whether the family is designable or not (max t,
always feasible), so the outcome does not matter for timing.  Per cell: cold
time (fresh cache: build + canonicalize + solve), warm wall time and
Clarabel's own time (medians), and the SDP's size: r*n_drop LMI blocks of
size 2n, i.e. ``rows = r * n_drop * 2n`` LMI rows.  A least-squares fit of
``log t = c + a log n + b log r + d log n_drop`` states the growth.
"""

from __future__ import annotations

import itertools
import statistics
import time

import numpy as np

NS = (2, 4, 8, 16)
RS = (1, 2, 4)
NDROPS = (2, 4, 8)


def run_grid(repeats: int = 5, max_rows: int = 512, cell_limit: float = 60.0, echo=print):
    from solver import SolverFailed, design
    from solver.compiled import problem_cache

    from .cases import random_family

    design(random_family(2, 1, 1, seed=99), 2, method="lmi")  # first-use costs, not a cell
    rows_out = []
    for n, r, N in itertools.product(NS, RS, NDROPS):
        rows = r * N * 2 * n
        cell = {"n": n, "r": r, "N": N, "rows": rows}
        if rows > max_rows:
            cell["note"] = f"skipped: {rows} LMI rows > limit {max_rows}"
            rows_out.append(cell)
            continue
        fam = random_family(n, r, 1, seed=1000 + 100 * n + 10 * r + N)
        problem_cache.clear()
        try:
            t0 = time.perf_counter()
            res = design(fam, N, method="lmi", time_limit=cell_limit)
            cell["cold"] = time.perf_counter() - t0
            cell["outcome"] = res.outcome
            walls, solv = [], []
            for _ in range(repeats):
                t0 = time.perf_counter()
                res = design(fam, N, method="lmi", time_limit=cell_limit)
                walls.append(time.perf_counter() - t0)
                solv.append(res.timings["solver"])
                if sum(walls) > cell_limit:
                    break
            cell["warm"] = statistics.median(walls)
            cell["clarabel"] = statistics.median(solv)
            cell["runs"] = len(walls)
        except SolverFailed as err:
            cell["note"] = f"SolverFailed({getattr(err, 'status', '')}) within {cell_limit:g} s"
        rows_out.append(cell)
        echo(f"  grid n={n} r={r} N={N}: {cell.get('warm', cell.get('note'))}", flush=True,
             file=__import__("sys").stderr)
    return rows_out


def fit(cells, key):
    """Exponents of ``t ~ n^a r^b N^d`` and of ``t ~ rows^e`` (least squares in logs)."""
    pts = [c for c in cells if key in c and c[key] > 0]
    if len(pts) < 5:
        return None
    y = np.log([c[key] for c in pts])
    X = np.column_stack([np.ones(len(pts)), np.log([c["n"] for c in pts]), np.log([c["r"] for c in pts]),
                         np.log([c["N"] for c in pts])])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    Xr = np.column_stack([np.ones(len(pts)), np.log([c["rows"] for c in pts])])
    coef_r, *_ = np.linalg.lstsq(Xr, y, rcond=None)
    return {"n": coef[1], "r": coef[2], "N": coef[3], "rows": coef_r[1]}


def grid_table(cells) -> str:
    from .solver_bench import fmt_t

    lines = ["| n | r | n_drop | LMI rows r*N*2n | cold | warm (median) | Clarabel | warm/Clarabel | outcome |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c in cells:
        if "warm" not in c:
            lines.append(f"| {c['n']} | {c['r']} | {c['N']} | {c['rows']} | | {c.get('note', '')} | | | |")
            continue
        lines.append(f"| {c['n']} | {c['r']} | {c['N']} | {c['rows']} | {fmt_t(c['cold'])} | {fmt_t(c['warm'])} "
                     f"| {fmt_t(c['clarabel'])} | {c['warm'] / c['clarabel']:.2f}x | {c['outcome']} |")
    out = "\n".join(lines)
    for key, label in (("warm", "warm wall"), ("clarabel", "Clarabel"), ("cold", "cold wall")):
        f = fit(cells, key)
        if f:
            out += (f"\n{label}: t ~ n^{f['n']:.2f} r^{f['r']:.2f} n_drop^{f['N']:.2f};"
                    f"  t ~ rows^{f['rows']:.2f}")
    return out
