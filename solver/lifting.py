"""Lifted interval systems: cost and disturbance channels over one inter-packet interval.

Per sample, plant mode l: ``x(k+1) = F_l x(k) + G_l u(k) + E_l w(k)``, performance output
``z(k) = C_l x(k) + D_l u(k)``; the buffer applies ``u(i_m + t) = K_{t+1} x(i_m)``.  Over one
interval (mode s of a :class:`solver.network.ModeSet`: the plant index of each of its ``eta``
samples) this lifts to (docs/design.md, "Performance: the lifted interval system")::

    M_0 = I,  M_{t+1} = F_{l_t} M_t + G_{l_t} K_{t+1}        x(i_m + t) = M_t x(i_m)   (w = 0)
    A = M_eta                                                  the interval map A_s(K)
    B = [Phi(eta, 1) E_{l_0}, ..., E_{l_{eta-1}}]              w over the interval, oldest first
    C = [C_{l_t} M_t + D_{l_t} K_{t+1}]_t                      z(i_m .. i_m + eta - 1)
    D = block lower triangular, (t, s) = C_{l_t} Phi(t, s+1) E_{l_s} for s < t
    L = [Q^{1/2} M_0; ...; Q^{1/2} M_{eta-1}; R^{1/2} K_1; ...; R^{1/2} K_eta]
    S = L^T L = sum_t M_t^T Q M_t + K_{t+1}^T R K_{t+1}       stage cost of the interval

with ``Phi(t, s) = F_{l_{t-1}} ... F_{l_s}``.  A, C and L are affine in the gains (every row block is
``free + sum_q coef_q K_q``), B and D do not depend on them.  This module is the one place the lifted
data are built; the design LMIs (:mod:`solver.methods.performance`) and the brackets
(:mod:`solver.brackets`) read them from here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InvalidInput
from .network import ModeSet


@dataclass(frozen=True, eq=False)
class AffineRows:
    """Rows ``free + sum_q coef[q] @ K_{q+1}`` affine in the gains.

    Attributes
    ----------
    free : ndarray, shape (k, n)
    coef : ndarray, shape (n_drop, k, m)
    """

    free: np.ndarray
    coef: np.ndarray

    def value(self, gains: np.ndarray) -> np.ndarray:
        """The rows for gains of shape (n_drop, m, n)."""
        return self.free + np.einsum("qkm,qmn->kn", self.coef, gains)

    def scheme(self, gain_map: np.ndarray) -> np.ndarray:
        """Coefficients of the scheme's free gains ``Theta_j`` (``K_q = sum_j M[q, j] Theta_j``): (J, k, m)."""
        return np.einsum("qkm,qj->jkm", self.coef, gain_map)

    def times_w(self, W, Y, gain_map: np.ndarray):
        """``rows(K) W`` with ``Y_j = Theta_j W``: ``free W + sum_j coef_j Y_j`` (numpy or cvxpy W, Y)."""
        out = self.free @ W
        for j, c in enumerate(self.scheme(gain_map)):
            if np.any(c):
                out = out + c @ Y[j]
        return out


#: Absolute errors of underflow, added to every entrywise bound of the loop data.
TINY = 64 * np.finfo(float).tiny


def interval_loop(free, dfree, coef, dcoef, K, eta: int):
    """``free + sum_q coef_q K_q`` (q < eta) in float64 and an entrywise bound of its distance to the same sum of
    the exact interval data (``free``, ``coef`` within ``dfree``, ``dcoef``) in real arithmetic: the a-priori bound
    ``gamma_k sum |terms|`` of the sum (Higham §3.1), doubled to cover the rounding of the bound itself.

    free, dfree : (n, n); coef, dcoef : (N, n, m); K : (N, m, n).
    """
    from .certificates import gamma

    m = coef.shape[-1]
    value = free + np.einsum("qam,qmb->ab", coef[:eta], K[:eta])
    terms = np.abs(free) + np.einsum("qam,qmb->ab", np.abs(coef[:eta]), np.abs(K[:eta]))
    err = dfree + np.einsum("qam,qmb->ab", dcoef[:eta], np.abs(K[:eta])) + gamma(eta * m + 2) * terms
    return value, 2 * err + TINY


def close(X, X_alt, dX_alt):
    """An entrywise bound of ``|X - X_true|`` from ``|X_alt - X_true| <= dX_alt`` (rounded up)."""
    return (np.abs(X - X_alt) * (1 + 4 * np.finfo(float).eps) + dX_alt) * (1 + 4 * np.finfo(float).eps) + TINY


@dataclass(frozen=True, eq=False)
class LiftedMode:
    """The lifted data of one interval mode (see the module docstring).

    Attributes
    ----------
    eta : int
    plants : tuple of int
        Plant mode of each sample of the interval.
    state : AffineRows
        ``A = M_eta`` (n rows).
    cost : AffineRows or None
        ``L`` (``eta (n + m)`` rows) when weights were given.
    output : AffineRows or None
        The lifted ``C`` (``eta p_z`` rows) when a disturbance channel was given.
    B : ndarray, shape (n, eta p_w), or None
    D : ndarray, shape (eta p_z, eta p_w), or None
    """

    eta: int
    plants: tuple
    state: AffineRows
    cost: AffineRows | None
    output: AffineRows | None
    B: np.ndarray | None
    D: np.ndarray | None


@dataclass(frozen=True, eq=False)
class Lifted:
    """Lifted interval systems of every mode of a :class:`ModeSet`.

    Attributes
    ----------
    modes : ModeSet
    lifted : list of LiftedMode
        One per mode, in the ModeSet's order.
    Q, R : ndarray or None
        Cost weights (n x n positive semidefinite, m x m positive definite).
    channel : (E, C, D) or None
        The plant's disturbance channel per plant mode (:func:`check_channel`), for :meth:`errors`.
    """

    modes: ModeSet
    lifted: list
    Q: np.ndarray | None = None
    R: np.ndarray | None = None
    channel: tuple | None = None

    @property
    def has_cost(self) -> bool:
        return self.Q is not None

    @property
    def has_disturbance(self) -> bool:
        return self.lifted[0].B is not None

    def channel_sizes(self) -> dict:
        """``n_disturbances`` (p_w) and ``n_outputs`` (p_z) of the disturbance channel, the keywords of
        :func:`solver.compiled.design_size` (empty without a channel)."""
        lm = self.lifted[0]
        if lm.B is None:
            return {}
        return {"n_disturbances": lm.B.shape[1] // lm.eta, "n_outputs": lm.D.shape[0] // lm.eta}

    def numeric(self, gains: np.ndarray, errors: bool = True) -> list[dict]:
        """Per mode ``{"A", "L", "S", "B", "C", "D"}`` for given gains (missing channels are None).

        With ``errors`` (and the plant data on the ModeSet) each dict also holds ``"dA"``, ``"dS"``, ``"dB"``,
        ``"dC"``, ``"dD"``: entrywise bounds of the distance of these float64 matrices to the deployed loop's,
        built exactly from the float64 F, G, K (and Q, R, E, C_z, D_z), see :meth:`errors`.
        """
        out = []
        for lm in self.lifted:
            L = None if lm.cost is None else lm.cost.value(gains)
            out.append({
                "A": lm.state.value(gains),
                "L": L,
                "S": None if L is None else L.T @ L,
                "B": lm.B,
                "C": None if lm.output is None else lm.output.value(gains),
                "D": lm.D,
            })
        if errors and self.modes.F is not None:
            self.errors(gains, out)
        return out

    def errors(self, gains: np.ndarray, data: list[dict]) -> None:
        """Add to ``data`` (from :meth:`numeric`) entrywise bounds ``dA >= |A_true - A|`` (and ``dS``, ``dB``,
        ``dC``, ``dD`` where the data and the plant's channel are there; missing ones are None).

        ``A_true`` is the deployed interval loop: the products of the float64 F, G and gains in real arithmetic.
        The float64 ``A = free + sum_q coef_q K_q`` can be far from it in relative terms where ``G K`` nearly
        cancels ``F``; the re-checks of :mod:`solver.brackets` add the effect to their allowance
        (docs/design.md §8.4).  The products over the interval and their bounds come from
        :func:`solver.certificates.interval_data` (extended precision where there is one); the rest is a
        float64 sum with its a-priori bound ``gamma_k sum |terms|`` (Higham §3.1), doubled to cover the rounding of
        the bounds themselves.
        """
        from .certificates import gamma, interval_data

        F, G = self.modes.F, self.modes.G
        n, m = G.shape[1], G.shape[2]
        K = np.asarray(gains, dtype=np.float64)
        N = K.shape[0]
        absK = np.abs(K)
        eye = np.eye(N)

        def loop(free, dfree, coef, dcoef, eta):
            return interval_loop(free, dfree, coef, dcoef, K, eta)

        plants = [lm.plants for lm in self.lifted]
        free, dfree, coef, dcoef = interval_data(F, G, plants, eye)
        need_prefix = any(d["S"] is not None or d["C"] is not None for d in data)
        if need_prefix:
            prefixes = [seq[:t] for seq in plants for t in range(len(seq))]
            pfree, dpfree, pcoef, dpcoef = interval_data(F, G, prefixes, eye)
        ch = self.channel
        if ch is not None and any(d["B"] is not None for d in data):
            E = np.asarray(ch[0], dtype=np.float64)
            pw = E.shape[2]
            Nb = max(len(seq) for seq in plants)
            _, _, bq, dbq = interval_data(F, E, plants, np.eye(Nb))
            _, _, pbq, dpbq = interval_data(F, E, prefixes if need_prefix else [()], np.eye(Nb))
        at = 0
        for s, (seq, d) in enumerate(zip(plants, data)):
            eta = len(seq)
            # the deployed loop's ingredients, for the exact re-checks (rebuilt in rationals there)
            d["plant"] = {"F": [F[l] for l in seq], "G": [G[l] for l in seq], "K": K[:eta], "Q": self.Q,
                          "R": self.R, "channel": None if ch is None else tuple(np.asarray(X)[list(seq)] for X in ch)}
            A_alt, dA_alt = loop(free[s], dfree[s], coef[s], dcoef[s], eta)
            d["dA"] = close(d["A"], A_alt, dA_alt)
            d["dS"] = d["dB"] = d["dC"] = d["dD"] = None
            Ms = []
            if need_prefix:
                for t in range(eta):
                    Ms.append(loop(pfree[at + t], dpfree[at + t], pcoef[at + t], dpcoef[at + t], t))
            if d["S"] is not None and self.Q is not None:
                Q, R = self.Q, self.R
                aQ, aR = np.abs(Q), np.abs(R)
                S_alt, err, terms = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
                for t, (M, dM) in enumerate(Ms):
                    aM = np.abs(M)
                    S_alt += M.T @ Q @ M + K[t].T @ R @ K[t]
                    # |M'QM - Mt'QMt| <= dM'|Q|(|M| + dM) + (|M| + dM)'|Q| dM (the same for both factors)
                    err += dM.T @ aQ @ (aM + dM) + (aM + dM).T @ aQ @ dM
                    terms += aM.T @ aQ @ aM + absK[t].T @ aR @ absK[t]
                err += gamma(2 * (n + m + eta)) * terms
                d["dS"] = close(_symm(d["S"]), S_alt, 2 * err + TINY)
            if ch is not None and d["C"] is not None:
                Cz, Dz = np.asarray(ch[1], dtype=np.float64), np.asarray(ch[2], dtype=np.float64)
                rows, drows = [], []
                for t, (M, dM) in enumerate(Ms):
                    l = seq[t]
                    rows.append(Cz[l] @ M + Dz[l] @ K[t])
                    drows.append(2 * (np.abs(Cz[l]) @ dM + gamma(n + m + 1) * (np.abs(Cz[l]) @ np.abs(M)
                                                                                + np.abs(Dz[l]) @ absK[t])) + TINY)
                d["dC"] = close(d["C"], np.vstack(rows), np.vstack(drows))
            if ch is not None and d["B"] is not None:
                d["dB"] = close(d["B"], np.hstack(list(bq[s, :eta])), np.hstack(list(dbq[s, :eta])))
                pz = Cz.shape[1]
                D_alt, dD_alt = np.zeros((eta * pz, eta * pw)), np.zeros((eta * pz, eta * pw))
                for t in range(eta):
                    aC = np.abs(Cz[seq[t]])
                    for j in range(t):
                        X, dX = pbq[at + t, j], dpbq[at + t, j]
                        D_alt[t * pz:(t + 1) * pz, j * pw:(j + 1) * pw] = Cz[seq[t]] @ X
                        dD_alt[t * pz:(t + 1) * pz, j * pw:(j + 1) * pw] = \
                            2 * (aC @ dX + gamma(n + 1) * (aC @ np.abs(X))) + TINY
                d["dD"] = close(d["D"], D_alt, dD_alt)
            at += eta


def _symm(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + M.T)


def _psd_root(M: np.ndarray) -> np.ndarray:
    """Symmetric square root of a positive semidefinite matrix (tiny negative rounding clipped)."""
    vals, vecs = np.linalg.eigh(0.5 * (M + M.T))
    return (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ vecs.T


def _per_plant(value, r: int, rows: int | None, cols: int | None, name: str, field: tuple) -> np.ndarray:
    """One matrix for every plant mode, or a list with one per mode, as an (r, rows, cols) array."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInput(f"{name} must be a numeric matrix or a list of them (one per plant mode)", field) from None
    if arr.ndim == 1:
        arr = arr.reshape(-1, 1) if rows is not None and arr.size == rows else arr.reshape(1, -1)
    if arr.ndim == 2:
        arr = np.broadcast_to(arr, (r,) + arr.shape).copy()
    if arr.ndim != 3 or arr.shape[0] != r:
        raise InvalidInput(f"{name} must be one matrix or {r} matrices (one per plant mode), got shape "
                           f"{np.shape(value)}", field)
    if (rows is not None and arr.shape[1] != rows) or (cols is not None and arr.shape[2] != cols):
        raise InvalidInput(f"{name} must have shape ({rows if rows is not None else 'p'}, "
                           f"{cols if cols is not None else 'p'}), got {arr.shape[1:]}", field)
    if not np.all(np.isfinite(arr)):
        raise InvalidInput(f"{name} has NaN or infinite entries", field)
    return arr


#: The range of an input limit: its square enters the SDPs and the re-checks, and must stay a normal float64.
U_MAX_RANGE = (1e-150, 1e150)


def check_u_max(u_max, m: int) -> np.ndarray:
    """``u_max`` as m positive float64 within :data:`U_MAX_RANGE`, or InvalidInput naming the field."""
    try:
        u = np.array(u_max, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidInput("u_max must be a list of m positive numbers", ("u_max",)) from None
    if u.size != m or not np.all(np.isfinite(u)) or np.any(u <= 0):
        raise InvalidInput(f"u_max must have {m} positive finite entries", ("u_max",))
    low, high = U_MAX_RANGE
    if np.any(u < low) or np.any(u > high):
        raise InvalidInput(f"u_max entries must lie between {low:g} and {high:g} (their squares enter the "
                           "certificates); for inputs without a limit, leave u_max out", ("u_max",))
    return u


def check_weights(weights, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """``(Q, R)``: Q symmetric positive semidefinite n x n, R symmetric positive definite m x m."""
    if weights is None:
        return np.eye(n), np.eye(m)
    if isinstance(weights, dict) and set(weights) == {"Q", "R"}:  # the service's JSON form
        weights = (weights["Q"], weights["R"])
    if not isinstance(weights, (tuple, list)) or len(weights) != 2:
        raise InvalidInput("weights must be a pair (Q, R) or {\"Q\": ..., \"R\": ...}", ("weights",))
    out = []
    for i, (W, k, name) in enumerate(((weights[0], n, "Q"), (weights[1], m, "R"))):
        try:
            W = np.array(W, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidInput(f"{name} must be a numeric matrix", ("weights", i)) from None
        if W.ndim == 0 or (W.ndim == 1 and W.size == k):
            W = np.diag(np.broadcast_to(W, (k,)).astype(float))
        if W.shape != (k, k) or not np.all(np.isfinite(W)):
            raise InvalidInput(f"{name} must be a finite {k} x {k} matrix, got shape {W.shape}", ("weights", i))
        if not np.allclose(W, W.T, rtol=1e-12, atol=1e-14 * max(1.0, np.abs(W).max())):
            raise InvalidInput(f"{name} must be symmetric", ("weights", i))
        W = 0.5 * (W + W.T)
        low = np.linalg.eigvalsh(W)[0]
        # relative to the matrix's own size: the balanced weights (solver.scaling) of a large Q beside a small R
        # put R~ near 1e-13, a positive definite matrix the absolute floor refused
        scale = float(np.abs(W).max())
        if name == "Q" and low < -1e-12 * scale:
            raise InvalidInput("Q must be positive semidefinite", ("weights", 0))
        if name == "R" and low <= 1e-12 * scale:
            raise InvalidInput("R must be positive definite", ("weights", 1))
        out.append(W)
    return out[0], out[1]


def check_channel(disturbance, output, r: int, n: int, m: int):
    """``(E, C, D)`` per plant mode, shapes (r, n, p_w), (r, p_z, n), (r, p_z, m).

    ``output`` is the pair ``(C, D)`` (``D`` None means zero), each one matrix or one per plant mode,
    or None: ``z = [x; u]`` (C = [I; 0], D = [0; I]).
    """
    E = _per_plant(disturbance, r, n, None, "disturbance E", ("disturbance",))
    if output is None:
        C = np.broadcast_to(np.vstack([np.eye(n), np.zeros((m, n))]), (r, n + m, n)).copy()
        D = np.broadcast_to(np.vstack([np.zeros((n, m)), np.eye(m)]), (r, n + m, m)).copy()
        return E, C, D
    if isinstance(output, dict):  # the JSON form of the service, {"C": ..., "D": ...}
        unknown = sorted(set(output) - {"C", "D"})
        if unknown or "C" not in output:
            raise InvalidInput('output must be (C, D) or {"C": ..., "D": ...} (D optional)'
                               + (f"; unknown keys {unknown}" if unknown else ""), ("output",))
        output = (output["C"], output.get("D"))
    if not isinstance(output, (tuple, list)) or len(output) != 2:
        raise InvalidInput('output must be a pair (C, D) or {"C": ..., "D": ...}; D may be None', ("output",))
    C = _per_plant(output[0], r, None, n, "output C", ("output", 0))
    if output[1] is None:
        return E, C, np.zeros((r, C.shape[1], m))
    D = _per_plant(output[1], r, C.shape[1], m, "output D", ("output", 1))
    return E, C, D


def lift_modes(modes: ModeSet, weights=None, disturbance=None, output=None, *, cost: bool = True) -> Lifted:
    """Build the lifted interval systems of every mode.

    Parameters
    ----------
    modes : ModeSet
        Built with the plant data (``modes.F``, ``modes.G``).
    weights : (Q, R), optional
        Cost weights; with ``cost=True`` and None: ``Q = I``, ``R = I``.
    disturbance : array_like, optional
        ``E`` (n x p_w), one for all plant modes or one per mode.  Without it no channel is lifted.
    output : (C, D), C, or None
        Performance output ``z = C x + D u`` (p_z rows); one pair for all modes or one per mode.
    cost : bool
        Lift the cost rows L.
    """
    F, G = modes.F, modes.G
    r, n, m = G.shape
    N = modes.n_drop
    Q = R = Qh = Rh = None
    if cost:
        Q, R = check_weights(weights, n, m)
        Qh, Rh = _psd_root(Q), _psd_root(R)
    E = Cz = Dz = None
    if disturbance is not None:
        E, Cz, Dz = check_channel(disturbance, output, r, n, m)
    lifted = []
    for seq in modes.plants:
        eta = len(seq)
        free, coef = np.eye(n), np.zeros((N, n, m))
        cost_free, cost_coef, out_free, out_coef, out_w = [], [], [], [], []
        pw = 0 if E is None else E.shape[2]
        xw = np.zeros((n, eta * pw))  # effect of w(i_m .. i_m + eta - 1) on x(i_m + t)
        for t, l in enumerate(seq):
            if cost:
                cost_free.append(Qh @ free)
                cost_coef.append(np.einsum("ab,qbm->qam", Qh, coef))
            if E is not None:
                c_out = np.einsum("ab,qbm->qam", Cz[l], coef)
                c_out[t] += Dz[l]
                out_free.append(Cz[l] @ free)
                out_coef.append(c_out)
                out_w.append(Cz[l] @ xw)
                xw = F[l] @ xw
                xw[:, t * pw:(t + 1) * pw] += E[l]
            coef = np.einsum("ab,qbm->qam", F[l], coef)
            coef[t] += G[l]
            free = F[l] @ free
        cost_rows = out_rows = None
        if cost:
            u_free = np.zeros((eta * m, n))
            u_coef = np.zeros((N, eta * m, m))
            for t in range(eta):
                u_coef[t, t * m:(t + 1) * m] = Rh
            cost_rows = AffineRows(np.vstack(cost_free + [u_free]),
                                   np.concatenate([np.concatenate(cost_coef, axis=1), u_coef], axis=1))
        if E is not None:
            out_rows = AffineRows(np.vstack(out_free), np.concatenate(out_coef, axis=1))
        lifted.append(LiftedMode(
            eta=eta, plants=tuple(seq), state=AffineRows(free, coef), cost=cost_rows, output=out_rows,
            B=None if E is None else xw, D=None if E is None else np.vstack(out_w),
        ))
    return Lifted(modes=modes, lifted=lifted, Q=Q, R=R, channel=None if E is None else (E, Cz, Dz))
