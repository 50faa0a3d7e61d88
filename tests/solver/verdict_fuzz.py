"""Seeded fuzz of design verdicts against independent checks (used by test_verdict_fuzz.py and
scripts/fuzz_verdicts.py).

No verdict may be contradicted:

* "stabilized": our own float64 eigenvalue check of the returned certificate passes, and no
  interval map (nor a product of two) of the loop is *proven* unstable by exact arithmetic;
* "infeasible" with ``kind="uncontrollable"``: no method stabilizes the family;
* "infeasible" with ``kind="farkas"`` (lmi): no common quadratic design built from another method's
  stabilizing gains has relative margin >= the certificate's and gain norm < ``gain_bound``;
* "infeasible" with ``kind="farkas"`` (switched): likewise for the lmi design (Z = S_s = W);
* "infeasible" from Farkas only with ``any_margin`` (then no such design of any margin has gain norm
  < ``gain_bound_any_margin``); "marginal" only from a margin-only Farkas certificate.
"""

from __future__ import annotations

from collections import Counter
from fractions import Fraction

import numpy as np

from solver import PlantFamily, design
from solver.errors import InvalidInput, SolverFailed
from solver.exact import closed_loop, product, radius_at_least
from solver.lyapunov import common_lmi
from solver.network import ModeSet

KINDS = ("random", "near_uncontrollable", "badly_scaled", "weak", "uncontrollable")


def family(rng: np.random.Generator, kind: str) -> PlantFamily:
    n = int(rng.integers(2, 4))
    r = int(rng.integers(1, 3))
    F = rng.normal(size=(r, n, n))
    F *= rng.uniform(0.5, 1.5, size=(r, 1, 1)) / np.max(np.abs(np.linalg.eigvals(F)), axis=1)[:, None, None]
    G = rng.normal(size=(r, n, 1))
    if kind == "near_uncontrollable":
        # input nearly orthogonal to a left eigenvector of the first mode's largest eigenvalue
        vals, vecs = np.linalg.eig(F[0].T)
        w = np.real(vecs[:, np.argmax(np.abs(vals))])
        w /= np.linalg.norm(w)
        G = G - w[None, :, None] * (w @ G)[:, None, :] + 10.0 ** rng.uniform(-9, -3) * w[None, :, None]
    elif kind == "badly_scaled":
        d = 10.0 ** rng.uniform(-4, 4, size=n)
        F = F / d[None, :, None] * d[None, None, :]
        G = G / d[None, :, None]
    elif kind == "weak":
        G[:, 0, :] *= 10.0 ** rng.uniform(-5, -3)
    elif kind == "uncontrollable":
        F = np.tril(rng.normal(size=(r, n, n)) * 0.3, -1)
        for l in range(r):
            F[l][np.diag_indices(n)] = rng.uniform(-0.9, 0.9, size=n)
        F[:, 0, 0] = rng.choice([-1, 1]) * rng.uniform(1.0, 1.3)
        F[:, 0, 1:] = 0.0
        G[:, 0, :] = 0.0  # state 1 unstable, unreachable
    return PlantFamily(F=F, G=G)


def _own_recheck(modes: ModeSet, res) -> bool:
    """Our float64 re-check of a stabilized result's certificate (not the library's)."""
    A = modes.closed_loops(res.gains)
    if res.scaling and res.scaling.get("certificate") == "scaled":
        T = np.array(res.scaling["state"])
        A = A / T[None, :, None] * T[None, None, :]
    cert = res.certificate
    if cert.kind == "switched":
        P = 0.5 * (cert.P + np.swapaxes(cert.P, 1, 2))
        return all(np.linalg.eigvalsh(P[s])[0] > 0 and
                   np.linalg.eigvalsh(P[s] - A[s].T @ P[u] @ A[s])[0] > 0
                   for s in range(len(A)) for u in range(len(A)))
    X = 0.5 * (cert.X + cert.X.T)
    return np.linalg.eigvalsh(X)[0] > 0 and all(np.linalg.eigvalsh(X - a.T @ X @ a)[0] > 0 for a in A)


def _proven_unstable(fam: PlantFamily, modes: ModeSet, gains: np.ndarray) -> bool:
    maps = [closed_loop(fam.F, fam.G, gains, modes.plants[s]) for s in range(modes.n_modes)]
    if any(radius_at_least(M, Fraction(1)) for M in maps):
        return True
    return any(radius_at_least(product([maps[i], maps[j]]), Fraction(1))
               for i in range(len(maps)) for j in range(i + 1, len(maps)))


def _lmi_point(modes: ModeSet, gains: np.ndarray):
    """A common quadratic design for fixed gains: ``(tau, kappa)`` in the Farkas statement's terms, or None."""
    A = modes.closed_loops(gains)
    try:
        X, t, _ = common_lmi(A)
    except SolverFailed:
        return None
    X = 0.5 * (X + X.T)
    if not (t > 0 and np.linalg.eigvalsh(X)[0] > 0):
        return None
    W = np.linalg.inv(X)
    taus = []
    for a in A:
        L = np.block([[W, (a @ W).T], [a @ W, W]])
        taus.append(np.linalg.eigvalsh(0.5 * (L + L.T))[0] / np.trace(W))
    kappa = float(np.sqrt(sum(np.linalg.norm(K, 2) ** 2 for K in gains)))
    return min(taus), kappa


def run(count: int, seed: int = 0, max_switched_modes: int = 6):
    """Fuzz ``count`` families; returns ``(Counter of verdicts, list of contradictions)``."""
    rng = np.random.default_rng(seed)
    verdicts: Counter = Counter()
    contradictions: list = []
    for case in range(count):
        kind = KINDS[case % len(KINDS)]
        fam = family(rng, kind)
        n_drop = int(rng.integers(1, 6))
        try:
            modes = ModeSet.from_family(fam, n_drop)
        except InvalidInput:
            verdicts["invalid_input"] += 1
            continue
        results = {}
        methods = ["lmi"] + (["switched"] if modes.n_modes <= max_switched_modes else [])
        for method in methods:
            try:
                res = design(fam, n_drop, method=method, decay_rate=None)  # the verdicts of one SDP
            except (InvalidInput, SolverFailed) as err:
                verdicts[f"{method}:error:{type(err).__name__}"] += 1
                continue
            results[method] = res
            label = res.outcome if res.certificate is None or res.outcome == "stabilized" else (
                f"{res.outcome}/{res.certificate.kind}")
            verdicts[f"{method}:{label}"] += 1
        where = (case, kind, n_drop)
        for method, res in results.items():
            if res.outcome == "stabilized":
                if not _own_recheck(modes, res):
                    contradictions.append((where, method, "own float64 re-check fails"))
                if _proven_unstable(fam, modes, res.gains):
                    contradictions.append((where, method, "a mode or product is proven unstable"))
            elif res.outcome in ("infeasible", "marginal"):
                cert = res.certificate
                if not cert.verified:
                    contradictions.append((where, method, "unverified proof"))
                others = [o for m, o in results.items() if m != method and o.outcome == "stabilized"]
                if cert.kind == "uncontrollable" and others:
                    contradictions.append((where, method, "uncontrollable, yet another method stabilized"))
                if cert.kind == "farkas":
                    for other in others:
                        point = _lmi_point(modes, other.gains)
                        if point is not None and point[0] >= cert.margin and point[1] < cert.gain_bound:
                            contradictions.append((where, method, f"Farkas contradicted by {other.method}: {point}"))
                        # "infeasible" excludes every margin below its own gain bound
                        if (point is not None and res.outcome == "infeasible" and point[0] > 0
                                and point[1] < cert.gain_bound_any_margin):
                            contradictions.append((where, method, f"infeasible contradicted by {other.method}: "
                                                                  f"{point}"))
                if res.outcome == "marginal" and (cert.kind != "farkas" or cert.any_margin):
                    contradictions.append((where, method, "marginal without a margin-only Farkas certificate"))
                if res.outcome == "infeasible" and cert.kind == "farkas" and not cert.any_margin:
                    contradictions.append((where, method, "infeasible from a margin-only certificate"))
    return verdicts, contradictions
