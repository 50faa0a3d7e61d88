"""Cross-check of the structured IPM (solver/ipm/) against Clarabel on seeded random families.

``python -m bench ipm-check [--count N] [--seed S]`` prints the counts; the CI test
(tests/solver/test_ipm.py) runs a bounded sample of the same generator.

Each family is drawn by :func:`draw_case` over n 2..12, r 1..5, n_drop 1..10,
m 1..3 and a *kind*: modes near one nominal plant (often stabilizable),
independent modes (rarely), badly scaled states and inputs, a zero input
matrix, repeated modes, modes scaled to sit near the stabilizability
boundary, huge and tiny entries.  The lmi SDP is solved by both solvers; the
verdicts (``t* > margin``) must agree, ``t*`` must agree to ``tol`` relative
(absolute for ``|t*| < 1``), and a positive IPM ``t`` must be certified in
float64 by its own ``W, Y`` (every block's smallest eigenvalue > 0).

With ``--design`` every family is then designed through ``design()`` with ``solver="IPM"`` and
``solver="CLARABEL"`` (``lmi`` always, ``switched`` up to 8 modes): the outcome, the proof kind
(common_quadratic / switched / farkas / uncontrollable, each re-checked in float64) and any certified
decay rate must be identical; the largest t* difference is printed.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from solver import PlantFamily
from solver.network import ModeSet

KINDS = ("near", "independent", "scaled", "zero_g", "repeated", "boundary", "huge_tiny")
MARGIN = 1e-6


def draw_case(seed: int, max_n: int = 12, max_lmi_rows: int = 400):
    """A seeded random (ModeSet, description); the SDP has at most ``max_lmi_rows`` rows (r n_drop 2n)."""
    fam, N, desc = draw_family(seed, max_n, max_lmi_rows)
    return ModeSet.from_family(fam, N), desc


def draw_family(seed: int, max_n: int = 12, max_lmi_rows: int = 400):
    """The seeded random ``(PlantFamily, n_drop, description)`` behind :func:`draw_case`."""
    rng = np.random.default_rng(seed)
    kind = KINDS[seed % len(KINDS)]
    while True:
        n = int(rng.integers(2, max_n + 1))
        r = int(rng.integers(1, 6))
        N = int(rng.integers(1, 11))
        m = int(rng.integers(1, 4))
        if r * N * 2 * n <= max_lmi_rows:
            break
    F0 = rng.standard_normal((n, n))
    G0 = rng.standard_normal((n, m))
    Fs, Gs = [], []
    for _ in range(r):
        if kind == "independent":
            F, G = rng.standard_normal((n, n)), rng.standard_normal((n, m))
        else:
            F = F0 + 0.2 * rng.standard_normal((n, n))
            G = G0 + 0.2 * rng.standard_normal((n, m))
        F *= rng.uniform(0.9, 1.2) / max(np.max(np.abs(np.linalg.eigvals(F))), 1e-12)
        Fs.append(F)
        Gs.append(G)
    if kind == "repeated":
        Fs, Gs = [Fs[0]] * r, [Gs[0]] * r
    if kind == "zero_g":
        Gs = [np.zeros((n, m))] * r
    if kind == "scaled":
        D = np.diag(10.0 ** rng.uniform(-2, 2, n))
        Di = np.linalg.inv(D)
        Fs = [D @ F @ Di for F in Fs]
        Gs = [D @ G * 10.0 ** rng.uniform(-2, 2) for G in Gs]
    if kind == "huge_tiny":
        Fs = [F * (1.0 + 0.5 * rng.uniform()) for F in Fs]
        Gs = [G * 10.0 ** rng.choice([-6.0, 6.0]) for G in Gs]
    if kind == "boundary":
        # Stable modes with spectral radius close to 1 and a weak input: t* is small.
        Fs = [F * (0.995 / np.max(np.abs(np.linalg.eigvals(F)))) for F in Fs]
        Gs = [G * 1e-3 for G in Gs]
    fam = PlantFamily(F=Fs, G=Gs, name=f"{kind} seed={seed}")
    try:
        ModeSet.from_family(fam, N)
    except Exception:  # noqa: BLE001  (F^N overflow for very unstable draws: try a smaller N)
        N = 1
    return fam, N, f"{kind} n={n} r={r} N={N} m={m}"


def clarabel_solve(modes: ModeSet):
    """``(t*, W, Y)`` of the lmi SDP from Clarabel through the project's compiled cvxpy problem."""
    from solver.methods import lmi

    n, m, S, J = modes.n_states, modes.n_inputs, modes.n_modes, modes.n_free_gains
    compiled = lmi.build(n, m, S, J, modes.scheme_coef()[1])
    values = lmi.plant_values(modes)
    compiled.solve(values)
    W = compiled.value("W")
    return float(compiled.value("t")), 0.5 * (W + W.T), np.stack(compiled.value("Y"))


def clarabel_t(modes: ModeSet) -> float:
    return clarabel_solve(modes)[0]


def attained(modes: ModeSet, W: np.ndarray, Y: np.ndarray) -> float:
    """The t a point attains, in float64: ``min_s lambda_min(L_s(W, Y))`` scaled to ``trace W = n``."""
    coef, active = modes.scheme_coef()
    n = W.shape[0]
    c = n / np.trace(W)
    return float(np.linalg.eigvalsh(_blocks(modes, c * W, c * Y))[:, 0].min())


def _blocks(modes, W, Y):
    coef, active = modes.scheme_coef()
    AW = modes.free @ W + np.einsum("sjab,jbc->sac", coef * active[:, :, None, None], Y)
    n = W.shape[0]
    blocks = np.zeros((modes.n_modes, 2 * n, 2 * n))
    blocks[:, :n, :n] = W
    blocks[:, n:, n:] = W
    blocks[:, n:, :n] = AW
    blocks[:, :n, n:] = np.swapaxes(AW, 1, 2)
    return blocks


def certified(modes: ModeSet, W: np.ndarray, Y: np.ndarray) -> bool:
    """Every block ``[[W, (A_s W)^T], [A_s W, W]]`` positive definite in float64."""
    return bool(np.linalg.eigvalsh(_blocks(modes, W, Y))[:, 0].min() > 0)


def check_one(seed: int, tol: float = 1e-6, max_lmi_rows: int = 400) -> dict:
    from solver.ipm import solve_lmi

    modes, desc = draw_case(seed, max_lmi_rows=max_lmi_rows)
    coef, active = modes.scheme_coef()
    t0 = time.perf_counter()
    sol = solve_lmi(modes.free, coef, active)
    t_ipm = time.perf_counter() - t0
    t0 = time.perf_counter()
    try:
        t_ref, W_ref, Y_ref = clarabel_solve(modes)
        ref_status = "ok"
        att_ref = attained(modes, W_ref, Y_ref)
    except Exception as err:  # noqa: BLE001
        t_ref, ref_status, att_ref = float("nan"), f"clarabel failed: {err}", float("nan")
    t_cla = time.perf_counter() - t0
    att_ipm = attained(modes, sol.W, sol.Y)
    diff = abs(sol.t - t_ref) / max(1.0, abs(t_ref))
    same = (sol.t > MARGIN) == (t_ref > MARGIN)
    cert = certified(modes, sol.W, sol.Y) if sol.t > MARGIN else None
    # A t* difference beyond tol where the IPM's own point attains more than Clarabel's (in float64)
    # is Clarabel's inaccuracy, counted apart.
    ref_worse = bool(diff > tol and att_ipm > att_ref + tol * max(1.0, abs(t_ref)))
    return {"seed": seed, "desc": desc, "t_ipm": sol.t, "t_ref": t_ref, "diff": diff, "same_verdict": same,
            "certified": cert, "status": sol.status, "iterations": sol.iterations, "ref_status": ref_status,
            "attained_ipm": att_ipm, "attained_ref": att_ref, "ref_worse": ref_worse,
            "ok": bool(same and (diff <= tol or ref_worse) and cert in (None, True)
                       and sol.status in ("optimal", "inaccurate")),
            "time_ipm": t_ipm, "time_clarabel": t_cla}


def design_pair(fam, N, method: str, **kw) -> dict:
    """``design()`` with the IPM and with Clarabel: the verdicts, proofs and t* must be the same."""
    from solver import design

    out = {}
    for name in ("IPM", "CLARABEL"):
        t0 = time.perf_counter()
        try:
            res = design(fam, N, method=method, solver=name, **{"decay_rate": None, **kw})
            out[name] = {"outcome": res.outcome, "proof": None if res.certificate is None else res.certificate.kind,
                         "verified": None if res.certificate is None else bool(res.certificate.verified),
                         "t": res.history[0].objective if res.history else float("nan"),
                         "rate": res.decay_rate, "solver": res.solver, "time": time.perf_counter() - t0}
        except Exception as err:  # noqa: BLE001
            out[name] = {"outcome": f"error: {type(err).__name__}: {err}", "proof": None, "verified": None,
                         "t": float("nan"), "rate": None, "solver": name, "time": time.perf_counter() - t0}
    a, b = out["IPM"], out["CLARABEL"]
    return {"ipm": a, "ref": b, "same": a["outcome"] == b["outcome"] and a["proof"] == b["proof"]
            and a["rate"] == b["rate"], "dt": abs(a["t"] - b["t"]) / max(1.0, abs(b["t"]))}


def check_designs(seeds, max_lmi_rows: int, switched_max_modes: int = 8) -> int:
    """``design()`` both ways on the same families: lmi on every case, switched where it has at most
    ``switched_max_modes`` modes (the IPM's range under "AUTO")."""
    rows = []
    for seed in seeds:
        fam, N, desc = draw_family(seed, max_lmi_rows=max_lmi_rows)
        methods = ["lmi"] + (["switched"] if fam.n_modes * N <= switched_max_modes else [])
        for method in methods:
            r = design_pair(fam, N, method)
            r.update(seed=seed, desc=desc, method=method)
            rows.append(r)
            if not r["same"]:
                print(f"DESIGN MISMATCH seed {seed} {desc} {method}: IPM {r['ipm']} CLARABEL {r['ref']}", flush=True)
    for method in ("lmi", "switched"):
        sel = [r for r in rows if r["method"] == method]
        if not sel:
            continue
        counts: dict = {}
        for r in sel:
            key = (r["ipm"]["outcome"], r["ipm"]["proof"])
            counts[key] = counts.get(key, 0) + 1
        fin = [r["dt"] for r in sel if np.isfinite(r["dt"])]
        print(f"design(method={method!r}): cases {len(sel)}, identical verdicts and proofs {sum(r['same'] for r in sel)}"
              f"; max |dt*|/max(1,|t*|) {max(fin) if fin else float('nan'):.2e}; IPM outcomes "
              + ", ".join(f"{o} ({p}) {c}" for (o, p), c in sorted(counts.items(), key=str))
              + f"; time IPM {sum(r['ipm']['time'] for r in sel):.1f} s, Clarabel {sum(r['ref']['time'] for r in sel):.1f} s")
    return sum(not r["same"] for r in rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench ipm-check")
    p.add_argument("--count", type=int, default=300)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-rows", type=int, default=400)
    p.add_argument("--design", action="store_true",
                   help="also run design() with solver='IPM' and 'CLARABEL' on every case (verdicts, proofs, t*)")
    a = p.parse_args(argv)
    rows = []
    t0 = time.perf_counter()
    for seed in range(a.seed, a.seed + a.count):
        row = check_one(seed, max_lmi_rows=a.max_rows)
        rows.append(row)
        if not row["ok"]:
            print(f"MISMATCH seed {seed} {row['desc']}: ipm {row['t_ipm']:.9g} ({row['status']}, "
                  f"{row['iterations']} it) clarabel {row['t_ref']:.9g} ({row['ref_status']}) "
                  f"diff {row['diff']:.2e} certified {row['certified']}; attained in float64: ipm "
                  f"{row['attained_ipm']:.9g} clarabel {row['attained_ref']:.9g}", flush=True)
    n_ok = sum(r["ok"] for r in rows)
    same = sum(r["same_verdict"] for r in rows)
    pos = sum(r["t_ref"] > MARGIN for r in rows)
    cert = sum(bool(r["certified"]) for r in rows)
    solved = [r for r in rows if r["ref_status"] == "ok"]
    same = sum(r["same_verdict"] for r in solved)
    print(f"cases {len(rows)}, Clarabel solved {len(solved)}; verdicts agree {same}/{len(solved)} "
          f"({pos} stabilizable by Clarabel); "
          f"t* within 1e-6: {sum(r['diff'] <= 1e-6 for r in solved)}; max |dt|/max(1,|t|) "
          f"{max(r['diff'] for r in solved):.2e}; IPM designs certified in float64 {cert}/"
          f"{sum(r['t_ipm'] > MARGIN for r in rows)}; all checks pass {n_ok}/{len(rows)}")
    by = {}
    for r in rows:
        by.setdefault(r["status"], 0)
        by[r["status"]] += 1
    worse = [r for r in rows if r["ref_worse"]]
    print(f"t* differences > 1e-6 where Clarabel's own point attains less than the IPM's (Clarabel inaccurate): "
          f"{len(worse)}" + "".join(f"\n  seed {r['seed']} {r['desc']}: ipm {r['t_ipm']:.9g} clarabel {r['t_ref']:.9g} "
                                   f"(attained {r['attained_ipm']:.3g} vs {r['attained_ref']:.3g})" for r in worse))
    fails = [r for r in rows if r["ref_status"] != "ok"]
    print(f"Clarabel failed: {len(fails)}" + "".join(f"\n  seed {r['seed']} {r['desc']}: IPM {r['status']} "
                                                    f"t {r['t_ipm']:.6g}" for r in fails))
    print("IPM statuses:", by, f"; median iterations {np.median([r['iterations'] for r in rows]):.0f}, max "
          f"{max(r['iterations'] for r in rows)}")
    print(f"time: IPM {sum(r['time_ipm'] for r in rows):.1f} s, Clarabel via cvxpy (incl. build) "
          f"{sum(r['time_clarabel'] for r in rows):.1f} s; total {time.perf_counter() - t0:.0f} s")
    bad = check_designs(range(a.seed, a.seed + a.count), a.max_rows) if a.design else 0
    return 0 if n_ok == len(rows) and bad == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
