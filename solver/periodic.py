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
import scipy.linalg

#: Patterns (times frequencies) per stacked step: bounds the memory of the batched arrays ...
CHUNK = 4096
#: ... and bytes at most of one step's complex Gram stacks (three ``w x w`` per pattern and frequency, w the smaller
#: side of the lifted period): a 4-state loop with 30 disturbance entries per interval grown to periods of 6
#: (w = 180) would have taken 6.5 GB in one step of 4096 (the size guard refused the design for it).
STEP_BYTES = 256 * 2**20


def _step(count: int, n: int, w: int) -> int:
    """Patterns (or pairs) per batched step of ``count`` frequencies each: within :data:`CHUNK` and
    :data:`STEP_BYTES`."""
    per = 48.0 * count * (w * w + n * w + n * n)
    return int(max(1, min(CHUNK // max(1, count), STEP_BYTES // per)))


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
    step = _step(z.size, n, DtD.shape[-1])
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


def gram_gains(sys: dict, rows: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``sigma_max(H_p(e^{j w}))`` for the pairs ``(rows[i], omega[i])`` of a :func:`gram_form` stack, shape (K,)."""
    rows = np.asarray(rows, dtype=int)
    out = np.empty(rows.size)
    n = sys["Phi"].shape[1]
    eye = np.eye(n)
    step = _step(4, n, sys["DtD"].shape[-1])
    for lo in range(0, rows.size, step):
        r, w = rows[lo:lo + step], np.asarray(omega[lo:lo + step], dtype=float)
        X = np.linalg.solve(np.exp(1j * w)[:, None, None] * eye - sys["Phi"][r], sys["B"][r].astype(complex))
        Xh = np.conj(np.swapaxes(X, 1, 2))
        cross = Xh @ sys["CtD"][r]
        G = sys["DtD"][r] + cross + np.conj(np.swapaxes(cross, 1, 2)) + Xh @ sys["CtC"][r] @ X
        out[lo:lo + step] = np.sqrt(np.maximum(np.linalg.eigvalsh(G)[:, -1], 0.0))
    return out


#: Level-set search (:func:`level_set_norms`): relative gap between a level and the gain it was raised from ...
LEVEL_TOL = 1e-10
#: ... a pencil eigenvalue counts as on the unit circle when ``||z| - 1|`` is below this (a near-tangent one
#: only costs an evaluation: every crossing is confirmed by the gain at its interval's midpoint) ...
CIRCLE_TOL = 1e-6
#: ... and a pencil whose Cayley form or ``gamma^2 I - D'D`` is this ill-conditioned goes to the sweep instead.
PENCIL_COND = 1e10
#: ... and both of its Cayley forms (poles at z = 1, -1) when the gains there are within this of the level.
FLAT = 1e-4


def level_set_norms(sys: dict, floor: float = -np.inf, max_iter: int = 40, tol: float = LEVEL_TOL):
    """H-infinity norms of a stack of stable discrete systems by the level-set (symplectic pencil) iteration of
    Boyd-Balakrishnan / Bruinsma-Steinbuch (docs/design.md §8.4), all systems at once.

    For a level ``g`` with ``R = g^2 I - D'D`` invertible, ``g`` is a singular value of ``H(e^{jw})`` exactly when
    ``z = e^{jw}`` is an eigenvalue of the pencil ``M - z N``, ``M = [[A_g, B R^-1 B'], [0, I]]``,
    ``N = [[I, 0], [C'C + C'D R^-1 D'C, A_g']]``, ``A_g = A + B R^-1 D'C`` (eliminate the input from
    ``(g^2 I - H~ H) u = 0``).  Its Cayley form ``(M + N)^-1 (M - N)`` (``z = (1 + s) / (1 - s)``; ``M + N`` is
    invertible because the level is above the gain at ``z = -1``) is one batched ``eigvals`` of side 2n.
    Each system starts from the largest gain at ``w = 0``, ``pi`` and its slowest pole's angle; the gains at the
    midpoints between consecutive unit-circle eigenvalues at the level ``max(gain, floor) (1 + 2 LEVEL_TOL)``
    raise it (quadratic convergence to the peak) until no crossing is left.

    ``sys``: a :func:`gram_form` stack.  Returns ``(value, omega, status)``: ``value`` (P,) is always a gain
    evaluated at ``omega`` (a witnessed lower bound); status 0: converged (the norm is at most
    ``value (1 + 2 LEVEL_TOL)``), 1: not above ``floor`` (the norm is at most ``floor (1 + 2 LEVEL_TOL)``),
    2: the pencil was ill-conditioned or the iteration did not settle (the caller sweeps instead).
    """
    Phi, B, DtD, CtD, CtC = sys["Phi"], sys["B"], sys["DtD"], sys["CtD"], sys["CtC"]
    P, n = Phi.shape[:2]
    w = B.shape[2]
    lam = np.linalg.eigvals(Phi)
    slow = np.abs(np.angle(lam[np.arange(P), np.argmax(np.abs(lam) + 1e-3 * (np.abs(lam.imag) > 0), axis=1)]))
    start = np.stack([np.zeros(P), np.full(P, np.pi), slow], axis=1)
    gains = gram_gains(sys, np.repeat(np.arange(P), 3), start.ravel()).reshape(P, 3)
    arg = np.argmax(gains, axis=1)
    value, omega = gains[np.arange(P), arg], start[np.arange(P), arg]
    # the Cayley form's pole z = -c (M + c N is singular where the level is a gain at z = -c) where the gain is
    # further below the levels: a peak at w = 0 next to a pole at z = 1 made it 1e14-conditioned
    cay = np.where(gains[:, 0] <= gains[:, 1], -1.0, 1.0)
    ends = gains[:, :2]
    status = np.full(P, -1)
    I_n, I_w = np.eye(n), np.eye(w)
    for _ in range(max_iter):
        live = np.flatnonzero(status < 0)
        if not live.size:
            break
        above = value[live] > floor
        level = np.where(above, value[live], floor) * (1 + 2 * tol)
        R = level[:, None, None] ** 2 * I_w - DtD[live]
        r_eig = np.abs(np.linalg.eigvalsh(R))
        bad = ~(np.min(r_eig, axis=1) * PENCIL_COND > np.max(r_eig, axis=1))
        Bl = B[live]
        RDc = np.linalg.solve(R, np.swapaxes(CtD[live], 1, 2))
        Ag = Phi[live] + Bl @ RDc
        G = Bl @ np.linalg.solve(R, np.swapaxes(Bl, 1, 2))
        Q = CtC[live] + CtD[live] @ RDc
        Agt = np.swapaxes(Ag, 1, 2)
        c = cay[live][:, None, None]
        plus = np.block([[Ag + c * I_n, G], [c * Q, c * Agt + I_n]])
        minus = np.block([[Ag - c * I_n, G], [-c * Q, I_n - c * Agt]])
        with np.errstate(all="ignore"):
            try:
                X = np.linalg.solve(plus, minus)
            except np.linalg.LinAlgError:
                X = np.full(plus.shape, np.nan)
            bad |= ~np.all(np.isfinite(X), axis=(1, 2))
            X[bad] = 0.0
            s = np.linalg.eigvals(X).astype(complex)
            z = cay[live][:, None] * (1 + s) / (1 - s)
            # both z = +-1 within 1e-4 of the level (a flat response): the Cayley form is ill-conditioned at either
            # pole, so the pencil itself goes through QZ (scipy.linalg.eigvals(M, N), one system at a time)
            for i in np.flatnonzero(~bad & (np.min(ends[live], axis=1) > level * (1 - FLAT))):
                Mi = np.block([[Ag[i], G[i]], [np.zeros((n, n)), I_n]])
                Ni = np.block([[I_n, np.zeros((n, n))], [Q[i], Agt[i]]])
                try:
                    z[i] = scipy.linalg.eigvals(Mi, Ni)
                except (np.linalg.LinAlgError, ValueError):
                    bad[i] = True
            on = np.abs(np.abs(z) - 1) < CIRCLE_TOL
        status[live[bad]] = 2
        ang = np.where(on, np.abs(np.angle(z)), np.nan)
        ang[bad] = np.nan
        # 0 and pi close the list (the gains there are below the level): a crossing lost to rounding (a pair near
        # z = 1 pushed 1e-6 off the circle) still leaves an interval whose midpoint is above the level
        some = np.any(np.isfinite(ang), axis=1)[:, None]
        ang = np.sort(np.concatenate([ang, np.where(some, 0.0, np.nan), np.where(some, np.pi, np.nan)], axis=1),
                      axis=1)  # NaN last
        mids = 0.5 * (ang[:, 1:] + ang[:, :-1])
        rows, cols = np.nonzero(np.isfinite(mids))
        new = np.full(live.size, -np.inf)
        where = np.zeros(live.size)
        if rows.size:
            g = gram_gains(sys, live[rows], mids[rows, cols])
            order = np.lexsort((g, rows))  # per row, its largest gain last
            last = np.r_[rows[order][1:] != rows[order][:-1], True]
            new[rows[order][last]] = g[order][last]
            where[rows[order][last]] = mids[rows, cols][order][last]
        rise = (new > level) & ~bad
        idx = live[rise]
        value[idx], omega[idx] = new[rise], where[rise]
        done = ~rise & ~bad
        status[live[done & above]] = 0
        status[live[done & ~above]] = 1
    status[status < 0] = 2
    return value, omega, status
