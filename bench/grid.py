"""Growth grid: how the ``lmi`` design's cost grows with n, r and n_drop.

Each cell is a seeded random family (:func:`bench.cases.random_family`,
m = 1); the SDP is the same whether the family is designable or not (max t,
always feasible), so the outcome does not matter for timing.  Per cell: cold
time (fresh cache: build + canonicalize + solve), warm wall time and
Clarabel's own time (medians), Clarabel's iteration count, and the SDP's
size: r*n_drop LMI blocks of side 2n, i.e. ``rows = r * n_drop * 2n`` LMI
rows, and ``kkt = r * n_drop * t^2`` with ``t = n(2n+1)``: the entries of the
dense PSD blocks Clarabel puts into its KKT matrix.  Least-squares fits of
``log t = c + a log n + b log r + d log n_drop`` (and against rows, kkt)
state the growth.
"""

from __future__ import annotations

import itertools
import statistics
import time

import numpy as np

NS = (2, 4, 8, 16)
RS = (1, 2, 4)
NDROPS = (2, 4, 8)


def _clarabel_iterations():
    """Iterations of the last solve of the cached lmi problem (reads the cache; bench only)."""
    from solver.compiled import problem_cache

    for key in problem_cache.keys():
        if key and key[0] == "lmi":
            stats = problem_cache._items[key].problem.solver_stats
            return getattr(stats, "num_iters", None)
    return None


def run_grid(repeats: int = 5, max_rows: int = 256, cell_limit: float = 60.0, echo=print):
    from solver import SolverFailed, design
    from solver.compiled import problem_cache

    from .cases import random_family

    design(random_family(2, 1, 1, seed=99), 2, method="lmi", decay_rate=None)  # first-use costs, not a cell
    rows_out = []
    for n, r, N in itertools.product(NS, RS, NDROPS):
        rows = r * N * 2 * n
        cell = {"n": n, "r": r, "N": N, "rows": rows, "kkt": r * N * (n * (2 * n + 1)) ** 2}
        if rows > max_rows:
            cell["note"] = f"skipped: {rows} LMI rows > limit {max_rows}"
            rows_out.append(cell)
            continue
        fam = random_family(n, r, 1, seed=1000 + 100 * n + 10 * r + N)
        problem_cache.clear()
        try:
            t0 = time.perf_counter()
            res = design(fam, N, method="lmi", time_limit=cell_limit, decay_rate=None)
            cell["cold"] = time.perf_counter() - t0
            cell["outcome"] = res.outcome
            walls, solv = [], []
            for _ in range(max(1, min(repeats, int(cell_limit / 4 / max(cell["cold"], 1e-9))))):
                t0 = time.perf_counter()
                res = design(fam, N, method="lmi", time_limit=cell_limit, decay_rate=None)
                walls.append(time.perf_counter() - t0)
                solv.append(res.timings["solver"])
                if sum(walls) > cell_limit:
                    break
            cell["warm"] = statistics.median(walls)
            cell["clarabel"] = statistics.median(solv)
            cell["runs"] = len(walls)
            cell["iters"] = _clarabel_iterations()
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
    out = {"n": coef[1], "r": coef[2], "N": coef[3]}
    for size in ("rows", "kkt"):
        Xr = np.column_stack([np.ones(len(pts)), np.log([c[size] for c in pts])])
        coef_r, *_ = np.linalg.lstsq(Xr, y, rcond=None)
        out[size] = coef_r[1]
    return out


def grid_table(cells) -> str:
    from .solver_bench import fmt_t

    lines = ["| n | r | n_drop | LMI rows r*N*2n | KKT PSD entries | cold | warm (median) | Clarabel | warm/Clarabel "
             "| Clarabel iters | runs | outcome |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cells:
        if "warm" not in c:
            lines.append(f"| {c['n']} | {c['r']} | {c['N']} | {c['rows']} | {c['kkt']:.2g} | | {c.get('note', '')} "
                         f"| | | | | |")
            continue
        lines.append(f"| {c['n']} | {c['r']} | {c['N']} | {c['rows']} | {c['kkt']:.2g} | {fmt_t(c['cold'])} "
                     f"| {fmt_t(c['warm'])} | {fmt_t(c['clarabel'])} | {c['warm'] / c['clarabel']:.2f}x "
                     f"| {c['iters']} | {c['runs']} | {c['outcome']} |")
    out = "\n".join(lines)
    for key, label in (("warm", "warm wall"), ("clarabel", "Clarabel"), ("cold", "cold wall")):
        f = fit(cells, key)
        if f:
            out += (f"\n{label}: t ~ n^{f['n']:.2f} r^{f['r']:.2f} n_drop^{f['N']:.2f};"
                    f"  t ~ rows^{f['rows']:.2f};  t ~ kkt^{f['kkt']:.2f}")
    return out
