"""Batched values of many periodic patterns at once: the search behind a bracket's lower bound (docs/design.md §8.4).

All patterns of one length k share array shapes, so the lifted period systems, the periodic Lyapunov (Stein)
equations and the frequency sweeps run as stacked numpy operations instead of one Python loop per pattern:

* :func:`period_stack` builds ``Phi`` and the period's cost ``S_per = sum_i T_i' S_{s_i} T_i`` or its disturbance
  channel ``(B, C, D)`` for a stack of patterns (modes whose channels differ in width are padded with zero
  columns / rows: zero inputs and outputs do not change a singular value);
* :func:`stein_doubling` solves ``P = Phi' P Phi + S`` for the stack by doubling, ``P <- P + A' P A``,
  ``A <- A^2`` (after j steps ``P`` is the exact sum of the first ``2^j`` terms);
* :func:`sweep_gains` evaluates ``sigma_max(D + C (zI - Phi)^{-1} B)`` on a frequency grid through the Gram matrix
  of the smaller side, and :func:`gain_upper_bounds` a cheap upper bound of each pattern's H-infinity norm from
  the eigendecomposition of ``Phi``, used to skip patterns that cannot beat the best sweep value found.

The callers (:func:`solver.brackets.lower_bound`) re-evaluate the winning patterns exactly, one by one.
"""

from __future__ import annotations

import numpy as np

#: Patterns (times frequencies) per stacked step: bounds the memory of the batched arrays.
CHUNK = 4096


def group_by_length(pats: list) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{k: (positions in pats, mode indices (P_k, k))}`` for the patterns of each length k."""
    groups: dict[int, list] = {}
    for pos, seq in enumerate(pats):
        groups.setdefault(len(seq), []).append(pos)
    return {k: (np.array(pos), np.array([pats[p] for p in pos], dtype=int)) for k, pos in groups.items()}


def _padded(mats: list[np.ndarray], rows: int, cols: int) -> np.ndarray:
    out = np.zeros((len(mats), rows, cols))
    for i, M in enumerate(mats):
        out[i, :M.shape[0], :M.shape[1]] = M
    return out


def mode_arrays(data: list[dict]) -> dict:
    """The per-mode data as stacked arrays (disturbance channels zero-padded to a common width)."""
    out = {"A": np.stack([d["A"] for d in data])}
    if data[0].get("S") is not None:
        out["S"] = np.stack([d["S"] for d in data])
    if data[0].get("B") is not None:
        n = out["A"].shape[1]
        w = max(d["B"].shape[1] for d in data)
        r = max(d["C"].shape[0] for d in data)
        out["B"] = _padded([d["B"] for d in data], n, w)
        out["C"] = _padded([d["C"] for d in data], r, n)
        out["D"] = _padded([d["D"] for d in data], r, w)
    return out


def period_stack(arrays: dict, idx: np.ndarray, kind: str) -> dict:
    """Lifted period systems of the patterns ``idx`` (P, k): ``Phi`` and ``S`` (cost) or ``B, C, D`` (hinf)."""
    A = arrays["A"]
    P, k = idx.shape
    n = A.shape[1]
    T = np.broadcast_to(np.eye(n), (P, n, n)).copy()
    if kind == "cost":
        S = np.zeros((P, n, n))
        for i in range(k):
            S += np.swapaxes(T, 1, 2) @ arrays["S"][idx[:, i]] @ T
            T = A[idx[:, i]] @ T
        return {"Phi": T, "S": 0.5 * (S + np.swapaxes(S, 1, 2))}
    Bm, Cm, Dm = arrays["B"], arrays["C"], arrays["D"]
    w, r = Bm.shape[2], Cm.shape[1]
    Tw = np.zeros((P, n, k * w))
    C = np.empty((P, k * r, n))
    D = np.zeros((P, k * r, k * w))
    for i in range(k):
        s = idx[:, i]
        C[:, i * r:(i + 1) * r] = Cm[s] @ T
        D[:, i * r:(i + 1) * r] = Cm[s] @ Tw
        D[:, i * r:(i + 1) * r, i * w:(i + 1) * w] += Dm[s]
        Tw = A[s] @ Tw
        Tw[:, :, i * w:(i + 1) * w] += Bm[s]
        T = A[s] @ T
    return {"Phi": T, "B": Tw, "C": C, "D": D}


def spectral_radius(Phi: np.ndarray) -> np.ndarray:
    return np.max(np.abs(np.linalg.eigvals(Phi)), axis=-1)


def stein_doubling(Phi: np.ndarray, S: np.ndarray, max_steps: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """``P = sum_{i >= 0} Phi'^i S Phi^i`` for a stack of stable ``Phi`` by doubling.

    Returns ``(P, converged)``: a pattern converges when ``||A^(2^j)||_F^2`` falls below ``1e-18`` (the terms
    left are then below ``1e-18`` times the sum).  Unconverged patterns (spectral radius within ~1e-19 of 1)
    are for the caller to redo.
    """
    X = S.copy()
    Ak = Phi.copy()
    done = np.zeros(Phi.shape[0], dtype=bool)
    for _ in range(max_steps):
        live = ~done
        if not np.any(live):
            break
        Al, Xl = Ak[live], X[live]
        X[live] = Xl + np.swapaxes(Al, 1, 2) @ Xl @ Al
        Ak[live] = Al @ Al
        norm = np.sum(Ak[live] ** 2, axis=(1, 2))
        done[np.flatnonzero(live)[~(norm >= 1e-18)]] = True  # NaN (overflow) counts as done: rho >= 1 is screened
    return 0.5 * (X + np.swapaxes(X, 1, 2)), done


def stein_screened(Phi: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`stein_doubling` of a stack whose stability is not known: ``(P, stable, converged)``.

    A pattern whose doubling converged (``|Phi^(2^j)|_F^2 < 1e-18``, so ``rho(Phi) < 1e-9^(2^-j) < 1``) is stable
    without an eigenvalue; only the others (unstable ones overflow, or a radius within rounding of 1) take
    :func:`spectral_radius`.  The same verdicts as screening every pattern by its eigenvalues first (docs/design.md
    §8.4: n = 12, 50 loop modes, the batched ``eigvals`` of 4000 + 30 x 576 periods were 60 % of a cost bracket).
    ``stable``: ``rho < 1``; ``converged``: ``P`` is the sum's value (finite), only where ``stable``.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        P, done = stein_doubling(Phi, S)
        converged = done & np.all(np.isfinite(P), axis=(1, 2))
    stable = converged.copy()
    rest = np.flatnonzero(~converged)
    if rest.size:
        stable[rest] = spectral_radius(Phi[rest]) < 1
    return P, stable, converged


def _smaller_side(sys: dict) -> dict:
    """The transposed system when it has fewer outputs than inputs (same singular values)."""
    if sys["C"].shape[1] >= sys["B"].shape[2]:
        return sys
    t = lambda M: np.swapaxes(M, 1, 2)
    return {"Phi": t(sys["Phi"]), "B": t(sys["C"]), "C": t(sys["B"]), "D": t(sys["D"])}


def gram_form(sys: dict) -> dict:
    """The stack as :func:`sweep_gains` and :func:`gain_upper_bounds` use it: ``Phi``, ``B`` and the Gram products
    ``D'D``, ``C'D``, ``C'C`` of the side with fewer columns (the transposed system when it has fewer outputs than
    inputs: the same singular values).  Formed once per stack, the tall ``C``, ``D`` (``eta p_z`` rows per interval)
    are not sliced or multiplied again by every batch of the pruned sweep (docs/design.md §8.4)."""
    if "CtC" in sys:
        return sys
    sys = _smaller_side(sys)
    C, D = sys["C"], sys["D"]
    Ct = np.swapaxes(C, 1, 2)
    return {"Phi": sys["Phi"], "B": sys["B"], "DtD": np.swapaxes(D, 1, 2) @ D, "CtD": Ct @ D, "CtC": Ct @ C}


def sweep_gains(sys: dict, omega: np.ndarray) -> np.ndarray:
    """``max_f sigma_max(D + C (e^{j w_f} I - Phi)^{-1} B)`` for every system of the stack, shape (P,).

    ``sigma_max^2 = lambda_max(H^* H)`` with ``H^* H = D'D + X^* C'D + D'C X + X^* C'C X``,
    ``X = (zI - Phi)^{-1} B`` (the Gram matrix of the side with fewer columns).  ``sys``: the system stack or its
    :func:`gram_form`.
    """
    sys = gram_form(sys)
    Phi, B, DtD, CtD, CtC = sys["Phi"], sys["B"], sys["DtD"], sys["CtD"], sys["CtC"]
    P, n = B.shape[:2]
    z = np.exp(1j * np.asarray(omega, dtype=float))
    out = np.zeros(P)
    step = max(1, CHUNK // max(1, z.size))
    eye = np.eye(n)
    for lo in range(0, P, step):
        sl = slice(lo, min(P, lo + step))
        M = z[None, :, None, None] * eye - Phi[sl, None]  # (p, F, n, n)
        X = np.linalg.solve(M, np.broadcast_to(B[sl, None], M.shape[:2] + B.shape[1:]).astype(complex))
        Xh = np.conj(np.swapaxes(X, 2, 3))
        cross = Xh @ CtD[sl, None]
        G = DtD[sl, None] + cross + np.conj(np.swapaxes(cross, 2, 3)) + Xh @ CtC[sl, None] @ X
        out[sl] = np.sqrt(np.maximum(_largest_eigenvalues(G), 0.0))
    return out


def _largest_eigenvalues(G: np.ndarray, steps: int = 12) -> np.ndarray:
    """``max_f lambda_max(G[p, f])`` of a stack (p, F, w, w) of Hermitian PSD matrices, as eigvalsh would give it.

    A few power steps give Rayleigh quotients ``rho_pf <= lambda_max(G_pf)``; a frequency with
    ``||G_pf||_F <= max_f rho_pf`` cannot hold the maximum (``lambda_max <= ||G||_F``), so eigvalsh runs only on
    the others: the result is the same maximum, mostly without the cubic eigenvalue work.
    """
    w = G.shape[-1]
    if w <= 4:
        return np.max(np.linalg.eigvalsh(G)[..., -1], axis=1)
    v = np.ones(G.shape[:-1] + (1,), dtype=G.dtype)
    for _ in range(steps):
        v = G @ v
        v = v / np.maximum(np.linalg.norm(v, axis=(-2, -1), keepdims=True), 1e-300)
    rayleigh = np.real(np.conj(np.swapaxes(v, -1, -2)) @ G @ v)[..., 0, 0]
    lower = np.max(rayleigh, axis=1)
    frob = np.linalg.norm(G, axis=(-2, -1))
    need = frob > lower[:, None] * (1 - 1e-12)
    best = lower.copy()
    if np.any(need):
        lam = np.linalg.eigvalsh(G[need])[:, -1]
        rows = np.nonzero(need)[0]
        np.maximum.at(best, rows, lam)
    return best


def gain_upper_bounds(sys: dict) -> np.ndarray:
    """A cheap upper bound of every system's H-infinity norm (``inf`` when it cannot be trusted).

    With ``Phi = V diag(lambda) V^{-1}``: ``H(z) = D + sum_i (C V)_i (V^{-1} B)^i / (z - lambda_i)``, so
    ``||H(z)|| <= ||D||_2 + sum_i ||(C V)_i|| ||(V^{-1} B)^i|| / (1 - |lambda_i|)`` on the unit circle.  Used only
    to skip patterns in a search for a lower bound (a 1% allowance covers the rounding of the decomposition).
    ``sys``: the system stack or its :func:`gram_form` (then ``||(C V)_i||^2 = v_i^* C'C v_i`` and
    ``||D||_2^2 = lambda_max(D'D)``, of the transposed system where that side is smaller: the same norm).
    """
    sys = gram_form(sys)
    lam, V = np.linalg.eig(sys["Phi"])
    out = np.full(lam.shape[0], np.inf)
    cond = np.linalg.cond(V)
    ok = np.isfinite(cond) & (cond < 1e8) & (np.max(np.abs(lam), axis=1) < 1)
    if not np.any(ok):
        return out
    V, lam = V[ok], lam[ok]
    cv = np.sqrt(np.maximum(np.real(np.sum(np.conj(V) * (sys["CtC"][ok] @ V), axis=1)), 0.0))
    VB = np.linalg.solve(V, sys["B"][ok].astype(complex))
    terms = cv * np.linalg.norm(VB, axis=2) / (1 - np.abs(lam))
    d2 = np.sqrt(np.maximum(np.linalg.eigvalsh(sys["DtD"][ok])[:, -1], 0.0))
    out[ok] = (d2 + np.sum(terms, axis=1)) * 1.01
    out[np.isnan(out)] = np.inf  # a failed bound prunes nothing
    return out


def gains_at(sys: dict, omega: np.ndarray) -> np.ndarray:
    """``sigma_max(D + C (e^{j w} I - Phi)^{-1} B)`` of system p at its own frequencies ``omega[p]``: (P, K)."""
    z = np.exp(1j * np.asarray(omega, dtype=float))
    n = sys["Phi"].shape[1]
    M = z[..., None, None] * np.eye(n) - sys["Phi"][:, None]
    X = np.linalg.solve(M, np.broadcast_to(sys["B"][:, None], M.shape[:2] + sys["B"].shape[1:]).astype(complex))
    H = sys["D"][:, None] + sys["C"][:, None] @ X
    return np.linalg.svd(H, compute_uv=False)[..., 0]


def refined_peaks(sys: dict, points: int, peaks: int = 3, tol: float = 1e-12) -> np.ndarray:
    """The largest gain of every system: a ``points``-point sweep on [0, pi], then a golden-section search for a
    local maximum between the neighbours of each of its ``peaks`` best points (all systems and intervals at
    once).  A lower bound of each H-infinity norm; shape (P,)."""
    P = sys["Phi"].shape[0]
    omega = np.linspace(0.0, np.pi, points)
    grid = gains_at(sys, np.broadcast_to(omega, (P, points)))
    best = np.max(grid, axis=1)
    top = np.argsort(grid, axis=1)[:, -peaks:]
    lo = omega[np.maximum(top - 1, 0)]
    hi = omega[np.minimum(top + 1, points - 1)]
    g = (np.sqrt(5.0) - 1) / 2
    a, b = lo + (1 - g) * (hi - lo), lo + g * (hi - lo)
    fa, fb = gains_at(sys, a), gains_at(sys, b)
    while np.max(hi - lo) > tol:
        left = fa >= fb  # keep the maximum inside [lo, b] when f(a) >= f(b)
        hi = np.where(left, b, hi)
        lo = np.where(left, lo, a)
        a_new = np.where(left, lo + (1 - g) * (hi - lo), b)
        b_new = np.where(left, a, lo + g * (hi - lo))
        fresh = np.where(left, a_new, b_new)
        f_fresh = gains_at(sys, fresh)
        fa, fb = np.where(left, f_fresh, fb), np.where(left, fa, f_fresh)
        a, b = a_new, b_new
    return np.maximum(best, np.max(np.maximum(fa, fb), axis=1))
