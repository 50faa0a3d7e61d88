"""Output feedback: an observer at the controller, losses on both links (docs/design.md, "Output feedback").

The plant measures ``y(k) = C_l x(k)``.  A sensor link carries ``y(k)`` to the controller (at most
``sensor_n_drop - 1`` consecutive losses); the controller runs the predictor-observer every sample::

    with a measurement:   xh(k|k) = xh(k|k-1) + L_l (y(k) - C_l xh(k|k-1))
    without:              xh(k|k) = xh(k|k-1)
    always:               xh(k+1|k) = F_l xh(k|k) + G_l u(k)

(``u(k)`` is the input the actuator applied, known to the controller by acknowledgements) and sends
``[K_1 xh(k|k), ..., K_N xh(k|k)]`` over the control link to the actuator's buffer (today's buffer).

With the filtered error ``e(k) = x(k) - xh(k|k)`` the loop is block-triangular: per sample
``e(k+1) = (I - g(k+1) L_{l(k+1)} C_{l(k+1)}) F_{l(k)} e(k)`` (``g`` = 1 when the measurement arrived),
independent of ``x``; and over one control interval of ``eta`` samples starting at a delivered packet
``i``::

    x(i + eta) = A_s(K) x(i) - (A_s(K) - A_s(0)) e(i),

``A_s`` the interval map of :class:`solver.network.ModeSet`.  A block-diagonal quadratic function
``V = x' P x + e' Q_sigma e`` (``sigma``: measurements lost in a row so far) that decreases over every
interval, every admissible sensor pattern inside it and every next plant mode proves the whole loop
(plant, estimate, buffer) exponentially stable: :func:`joint_certificate` finds it, :func:`check_joint`
re-checks it in float64 without the solver.

Public entry points: :func:`design_observer` (the observer gains ``L``), :func:`joint_certificate`,
:func:`analyze_output` (given ``K`` and ``L``), :func:`simulate_output`, :func:`lqg_cost`.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import numpy as np

from .certificates import U, Prover
from .errors import InvalidInput, SolverFailed
from .network import PLANT_SWITCHING, ModeSet, check_gains, check_n_drop
from .plant import PlantFamily

#: Most sensor-pattern blocks the joint certificate may hold (each a 2n x 2n LMI).
MAX_JOINT_BLOCKS = 20_000

OBSERVER_KINDS = ("per_mode", "common")


# ------------------------------------------------------------------ inputs
def require_outputs(family: PlantFamily) -> np.ndarray:
    """``C`` of the family, shape (r, p, n); InvalidInput when the family has none."""
    if family.C is None:
        raise InvalidInput("output feedback needs the measured outputs: give the family C (y = C x), e.g. "
                           "PlantFamily(F=..., G=..., C=[[1, 0]])", ("C",))
    return np.asarray(family.C, dtype=np.float64)


def check_sensor_n_drop(sensor_n_drop) -> int:
    """``sensor_n_drop`` as an int >= 1 (at most ``sensor_n_drop - 1`` measurements lost in a row)."""
    if isinstance(sensor_n_drop, bool) or not isinstance(sensor_n_drop, (int, np.integer)) or not (
            1 <= sensor_n_drop <= 20):
        raise InvalidInput("sensor_n_drop must be an integer in 1..20 (at most sensor_n_drop - 1 measurements "
                           "lost in a row)", ("sensor_n_drop",))
    return int(sensor_n_drop)


def check_observer_gains(L, r: int, n: int, p: int) -> np.ndarray:
    """Observer gains as float64 (r, n, p); one (n, p) matrix is used for every plant mode."""
    try:
        arr = np.array(L, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInput("observer_gains must be numeric n x p matrices, one per plant mode",
                           ("observer_gains",)) from None
    if arr.ndim == 2 and arr.shape == (n, p):
        arr = np.repeat(arr[None], r, axis=0)
    if p == 1 and arr.ndim == 2 and arr.shape == (r, n):
        arr = arr[:, :, None]
    if arr.shape != (r, n, p):
        raise InvalidInput(f"observer_gains must have shape (r, n, p) = {(r, n, p)}, got {arr.shape}",
                           ("observer_gains",))
    if not np.all(np.isfinite(arr)):
        raise InvalidInput("observer_gains have NaN or infinite entries", ("observer_gains",))
    return arr


def check_noise(noise, n: int, p: int) -> tuple[np.ndarray, np.ndarray]:
    """``(W, V)``: process (n x n) and measurement (p x p) noise covariances, symmetric PSD (V > 0)."""
    try:
        W, V = (np.array(M, dtype=np.float64) for M in noise)
    except (TypeError, ValueError):
        raise InvalidInput("noise must be (W, V): the process (n x n) and measurement (p x p) covariances",
                           ("noise",)) from None
    if W.shape != (n, n) or V.shape != (p, p):
        raise InvalidInput(f"noise covariances must be {n} x {n} (W) and {p} x {p} (V)", ("noise",))
    for name, M, strict in (("W", W, False), ("V", V, True)):
        if not np.all(np.isfinite(M)) or not np.allclose(M, M.T, rtol=1e-12, atol=0.0):
            raise InvalidInput(f"noise {name} must be a finite symmetric matrix", ("noise", name))
        low = float(np.linalg.eigvalsh(M)[0])
        if low < 0 or (strict and low <= 0):
            raise InvalidInput(f"noise {name} must be positive {'definite' if strict else 'semidefinite'}",
                               ("noise", name))
    return W, V


# ------------------------------------------------------------------ sensor patterns
def sensor_runs(length: int, start: int, sensor_n_drop: int):
    """Every admissible arrival pattern of ``length`` samples after a node.

    Yields ``(arrivals, end)``: ``arrivals[t]`` is True when the measurement of sample ``t + 1`` arrives,
    ``end`` the number of measurements lost in a row after the last sample.  ``start`` is that count
    before the first one.
    """
    for bits in itertools.product((True, False), repeat=length):
        lost = start
        ok = True
        for got in bits:
            lost = 0 if got else lost + 1
            if lost > sensor_n_drop - 1:
                ok = False
                break
        if ok:
            yield bits, lost


def error_map(F, C, L, plants, next_plant: int, arrivals) -> np.ndarray:
    """The filtered error's map over one stretch: ``e(t0 + len) = E e(t0)``.

    ``plants[t]`` is the plant mode of sample ``t0 + t``, ``next_plant`` the mode after the stretch,
    ``arrivals[t]`` whether the measurement of sample ``t0 + t + 1`` arrived.
    """
    n = F.shape[1]
    E = np.eye(n)
    seq = tuple(plants) + (next_plant,)
    for t, got in enumerate(arrivals):
        step = F[seq[t]]
        if got:
            l_next = seq[t + 1]
            step = (np.eye(n) - L[l_next] @ C[l_next]) @ step
        E = step @ E
    return E


# ------------------------------------------------------------------ proofs that no observer exists
@dataclass
class ObserverObstruction:
    """A plant mode whose error no observer gain can drive to zero under one admissible sensor pattern.

    With ``sensor_n_drop - 1`` measurements lost, then one received, forever (plant mode ``mode``), the
    filtered error maps by ``(I - L C) F^M`` (``M = sensor_n_drop``).  ``vector`` spans an ``F^M``-invariant
    subspace inside ``ker C`` (exact: the unobservable subspace of ``(F^M, C)``, in rational arithmetic),
    on which that map is ``F^M`` whatever ``L``: an eigenvalue of modulus ``>= 1`` there means the estimate
    never converges, for every ``L``, and the loop's state ``(x, xh)`` is unbounded from some start.
    """

    mode: int
    eigenvalue: complex
    basis: np.ndarray
    period: int

    def to_dict(self) -> dict:
        return {"kind": "unobservable_pattern", "mode": self.mode,
                "eigenvalue": [float(self.eigenvalue.real), float(self.eigenvalue.imag)],
                "modulus": float(abs(self.eigenvalue)), "basis": self.basis.tolist(), "period": self.period}


def _rational_nullspace(rows):
    """Exact basis of the null space of a rational matrix (list of lists of Fraction)."""
    from fractions import Fraction

    A = [list(r) for r in rows]
    n = len(A[0]) if A else 0
    pivots = []
    row = 0
    for col in range(n):
        pr = next((i for i in range(row, len(A)) if A[i][col] != 0), None)
        if pr is None:
            continue
        A[row], A[pr] = A[pr], A[row]
        piv = A[row][col]
        A[row] = [v / piv for v in A[row]]
        for i in range(len(A)):
            if i != row and A[i][col] != 0:
                f = A[i][col]
                A[i] = [a - f * b for a, b in zip(A[i], A[row])]
        pivots.append(col)
        row += 1
        if row == len(A):
            break
    free = [c for c in range(n) if c not in pivots]
    basis = []
    for fc in free:
        v = [Fraction(0)] * n
        v[fc] = Fraction(1)
        for i, pc in enumerate(pivots):
            v[pc] = -A[i][fc]
        basis.append(v)
    return basis


def observer_obstruction(family: PlantFamily, sensor_n_drop: int) -> ObserverObstruction | None:
    """A proof that no observer gain works (:class:`ObserverObstruction`), or None when none was found."""
    from fractions import Fraction

    C = require_outputs(family)
    M = check_sensor_n_drop(sensor_n_drop)
    n = family.n_states
    for l in range(family.n_modes):
        Fq = [[Fraction(float(v)) for v in row] for row in family.F[l]]
        Cq = [[Fraction(float(v)) for v in row] for row in C[l]]

        def mul(X, Y):
            return [[sum(a * b for a, b in zip(r, c)) for c in zip(*Y)] for r in X]

        FM = Fq
        for _ in range(M - 1):
            FM = mul(FM, Fq)
        # Unobservable subspace of (F^M, C): kernel of [C; C F^M; ...; C F^{M(n-1)}], exact.
        rows, block = [], Cq
        for _ in range(n):
            rows.extend(block)
            block = mul(block, FM)
        basis = _rational_nullspace(rows)
        if not basis:
            continue
        Nb = np.array([[float(v) for v in b] for b in basis]).T  # (n, d)
        # F^M restricted to the invariant subspace: F^M N = N T, T from the exact basis.
        FMf = np.array([[float(v) for v in r] for r in FM])
        T = np.linalg.lstsq(Nb, FMf @ Nb, rcond=None)[0]
        eig = np.linalg.eigvals(T)
        k = int(np.argmax(np.abs(eig)))
        if len(basis) == 1:
            # One dimension: T is the exact ratio, decided in rational arithmetic.
            b = basis[0]
            i = next(j for j in range(n) if b[j] != 0)
            lam = sum(FM[i][j] * b[j] for j in range(n)) / b[i]
            if abs(lam) >= 1:
                return ObserverObstruction(l, complex(float(lam)), Nb, M)
            continue
        if abs(eig[k]) >= 1.0 + 1e-9:  # well clear of 1: the float64 eigenvalue of a small exact block
            return ObserverObstruction(l, complex(eig[k]), Nb, M)
    return None


# ------------------------------------------------------------------ the observer design
@dataclass
class ObserverDesign:
    """Observer gains and their certificate.

    Attributes
    ----------
    outcome : {"certified", "no_observer", "not_certified"}
        ``certified``: ``certificate`` (``Q_sigma``) passed :func:`check_error_certificate`;
        ``no_observer``: ``obstruction`` proves no gain exists; ``not_certified``: the sufficient LMI
        had no strictly feasible point (the solver's word, not a proof that no gain exists).
    gains : ndarray, shape (r, n, p), or None
        ``L_l`` per plant mode (equal when ``common``).
    certificate : ndarray, shape (sensor_n_drop, n, n), or None
        ``Q_sigma`` of the error's node-dependent quadratic function.
    decay_rate : float or None
        Per-sample rate the certificate proves for the error.
    kind : {"per_mode", "common", "kalman"}
    """

    outcome: str
    gains: np.ndarray | None
    certificate: np.ndarray | None
    decay_rate: float | None
    kind: str
    message: str = ""
    obstruction: ObserverObstruction | None = None
    #: With noise covariances: ``X_sigma`` (sensor_n_drop, n, n), a certified bound ``E[e e'] <= X_sigma`` under every
    #: admissible sensor pattern (:func:`error_covariance_bound`).
    error_bound: np.ndarray | None = None

    def to_dict(self) -> dict:
        return {
            "error_bound": None if self.error_bound is None else self.error_bound.tolist(),
            "outcome": self.outcome,
            "gains": None if self.gains is None else self.gains.tolist(),
            "certificate": None if self.certificate is None else self.certificate.tolist(),
            "decay_rate": self.decay_rate,
            "kind": self.kind,
            "message": self.message,
            "obstruction": None if self.obstruction is None else self.obstruction.to_dict(),
        }


def _error_blocks(F, C, L, M: int, rho: float):
    """``(Phi, to, frm)`` of every per-sample error transition: ``Phi' Q_to Phi <= rho^2 Q_frm`` certifies."""
    r = F.shape[0]
    n = F.shape[1]
    out = []
    for l, l_next in itertools.product(range(r), repeat=2):
        for sigma in range(M):
            out.append(((np.eye(n) - L[l_next] @ C[l_next]) @ F[l], 0, sigma))
            if sigma + 1 <= M - 1:
                out.append((F[l], sigma + 1, sigma))
    return out


def _upper_with_rounding(Mat: np.ndarray, scale: float, prover: Prover) -> float:
    """A rigorous upper bound of ``lambda_max(Mat)``, ``Mat`` computed in float64 from data of size ``scale``."""
    k = Mat.shape[0]
    err = 8 * (k + 2) * U * scale  # products of three k x k float64 matrices, summed
    return prover.max_upper(Mat, err)


def check_error_certificate(F, C, L, Q, M: int, rho: float = 1.0) -> bool:
    """Float64 re-check that ``Q_sigma`` certifies the filtered error (independent of any solver)."""
    prover = Prover()
    for sigma in range(M):
        if prover.min_lower(Q[sigma]) <= 0:
            return False
    for Phi, to, frm in _error_blocks(F, C, L, M, rho):
        Mat = Phi.T @ Q[to] @ Phi - rho**2 * Q[frm]
        scale = float(np.linalg.norm(Phi) ** 2 * np.linalg.norm(Q[to]) + np.linalg.norm(Q[frm]))
        if _upper_with_rounding(Mat, scale, prover) >= 0:
            return False
    return True


def _solve(prob, time_limit=None):
    import cvxpy as cp

    opts = {} if time_limit is None else {"time_limit": float(time_limit)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            prob.solve(solver=cp.CLARABEL, **opts)
        except cp.error.SolverError as err:
            raise SolverFailed(f"CLARABEL failed on the observer LMI: {err}", status="solver_error") from err
    return prob.status


def kalman_gains(family: PlantFamily, noise) -> np.ndarray:
    """The steady-state (filtered) Kalman gain of every plant mode, shape (r, n, p).

    ``L = P C' (C P C' + V)^-1`` with ``P`` the predicted error covariance of the filter Riccati equation
    ``P = F P F' - F P C' (C P C' + V)^-1 C P F' + W`` (``scipy.linalg.solve_discrete_are``).
    """
    from scipy.linalg import solve_discrete_are

    C = require_outputs(family)
    n, p = family.n_states, C.shape[1]
    W, V = check_noise(noise, n, p)
    out = np.empty((family.n_modes, n, p))
    for l in range(family.n_modes):
        P = solve_discrete_are(family.F[l].T, C[l].T, W, V)
        out[l] = P @ C[l].T @ np.linalg.inv(C[l] @ P @ C[l].T + V)
    return out


def certify_observer(family: PlantFamily, L, sensor_n_drop: int, decay_rate: float | None = None,
                     time_limit: float | None = None) -> np.ndarray | None:
    """``Q_sigma`` certifying given observer gains (LMI in Q, re-checked in float64), or None."""
    import cvxpy as cp

    C = require_outputs(family)
    M = check_sensor_n_drop(sensor_n_drop)
    F = np.asarray(family.F, dtype=np.float64)
    n = family.n_states
    L = check_observer_gains(L, family.n_modes, n, C.shape[1])
    rho = 1.0 if decay_rate is None else float(decay_rate)
    Q = [cp.Variable((n, n), symmetric=True) for _ in range(M)]
    t = cp.Variable()
    cons = [sum(cp.trace(q) for q in Q) == M * n]
    cons += [q >> t * np.eye(n) for q in Q]
    for Phi, to, frm in _error_blocks(F, C, L, M, rho):
        blk = rho**2 * Q[frm] - Phi.T @ Q[to] @ Phi
        cons.append(0.5 * (blk + blk.T) >> t * np.eye(n))
    prob = cp.Problem(cp.Maximize(t), cons)
    _solve(prob, time_limit)
    if t.value is None or Q[0].value is None or t.value <= 0:
        return None
    Qv = np.array([0.5 * (q.value + q.value.T) for q in Q])
    return Qv if check_error_certificate(F, C, L, Qv, M, rho) else None


def _covariance_steps(F, C, L, W, V, M: int):
    """``(Phi, N, to, frm)`` of every per-sample step of the filtered error's covariance: ``X+ = Phi X Phi' + N``."""
    r, n = F.shape[0], F.shape[1]
    out = []
    for l, l_next in itertools.product(range(r), repeat=2):
        gain = np.eye(n) - L[l_next] @ C[l_next]
        for sigma in range(M):
            out.append((gain @ F[l], gain @ W @ gain.T + L[l_next] @ V @ L[l_next].T, 0, sigma))
            if sigma + 1 <= M - 1:
                out.append((F[l], W, sigma + 1, sigma))
    return out


def check_error_bound(F, C, L, W, V, X, M: int) -> bool:
    """Float64 re-check (proven Cholesky bounds) that ``X_to - Phi X_from Phi' - N >= 0`` for every step."""
    prover = Prover()
    for Phi, Nz, to, frm in _covariance_steps(F, C, L, W, V, M):
        R = X[to] - Phi @ X[frm] @ Phi.T - Nz
        scale = float(np.linalg.norm(X[to]) + np.linalg.norm(Phi) ** 2 * np.linalg.norm(X[frm]) + np.linalg.norm(Nz))
        if prover.min_lower(0.5 * (R + R.T), 8 * (R.shape[0] + 2) * U * scale) < 0:
            return False
    return True


def error_covariance_bound(family: PlantFamily, observer_gains, sensor_n_drop: int, noise,
                           time_limit: float | None = None) -> np.ndarray | None:
    """A certified bound on the estimation error's covariance under every admissible sensor pattern.

    With ``x+ = F x + G u + w``, ``y = C x + v`` (covariances ``W``, ``V``) the filtered error's covariance
    steps by ``X+ = (I - L C) (F X F' + W) (I - L C)' + L V L'`` after a measurement and ``F X F' + W`` after a
    loss.  ``X_sigma`` (node ``sigma`` = measurements lost in a row) with ``X_to >= Phi X_from Phi' + N`` for
    every step bounds ``E[e e']`` at every sample of every admissible pattern (by induction, from any start
    below it).  Minimizes ``sum trace X_sigma`` with Clarabel; returns the ``X`` that passed
    :func:`check_error_bound` (slightly enlarged so that the check is strict), or None.
    """
    import cvxpy as cp

    C = require_outputs(family)
    M = check_sensor_n_drop(sensor_n_drop)
    n, p = family.n_states, C.shape[1]
    L = check_observer_gains(observer_gains, family.n_modes, n, p)
    W, V = check_noise(noise, n, p)
    F = np.asarray(family.F, dtype=np.float64)
    X = [cp.Variable((n, n), symmetric=True) for _ in range(M)]
    cons = []
    for Phi, Nz, to, frm in _covariance_steps(F, C, L, W, V, M):
        R = X[to] - Phi @ X[frm] @ Phi.T - Nz
        cons.append(0.5 * (R + R.T) >> 0)
    prob = cp.Problem(cp.Minimize(sum(cp.trace(x) for x in X)), cons)
    _solve(prob, time_limit)
    if X[0].value is None:
        return None
    Xv = np.array([0.5 * (x.value + x.value.T) for x in X])
    # The solver's X sits on the boundary: grow it by a relative 1e-9 (and a hair) until the re-check passes.
    for grow in (1e-9, 1e-7, 1e-5, 1e-3):
        Xg = Xv * (1 + grow) + grow * np.trace(Xv[0]) / n * np.eye(n)
        if check_error_bound(F, C, L, W, V, Xg, M):
            return Xg
    return None


def design_observer(family: PlantFamily, sensor_n_drop: int, *, kind: str = "per_mode", decay_rate=None,
                    noise=None, time_limit: float | None = None) -> ObserverDesign:
    """Observer gains ``L`` for at most ``sensor_n_drop - 1`` lost measurements in a row, with a certificate.

    Parameters
    ----------
    family : PlantFamily
        With ``C`` (r, p, n).
    sensor_n_drop : int
    kind : {"per_mode", "common"}
        One ``L_l`` per plant mode (the mode is known at the controller) or one for all.
    decay_rate : float, optional
        Per-sample rate in (0, 1] the error must decay at (None: 1, stability).
    noise : (W, V), optional
        Process and measurement noise covariances: the Kalman gains of each mode are tried first
        (:func:`kalman_gains`, the optimum without losses) and kept when certified.

    Returns
    -------
    ObserverDesign
        The LMI (docs/design.md, "Output feedback"): variables ``Q_sigma`` and ``Y_l = Q_0 L_l``; for
        every plant mode pair ``(l, l')`` and node ``sigma``,
        ``[[rho^2 Q_sigma, F_l'(Q_0 - Y_l' C_l')'], [(Q_0 - Y_l' C_l') F_l, Q_0]] > 0`` (measurement) and
        ``F_l' Q_{sigma+1} F_l < rho^2 Q_sigma`` (loss, ``sigma + 1 <= M - 1``); ``L_l = Q_0^-1 Y_l``.
    """
    import cvxpy as cp

    C = require_outputs(family)
    M = check_sensor_n_drop(sensor_n_drop)
    if kind not in OBSERVER_KINDS:
        raise InvalidInput(f"observer must be one of {OBSERVER_KINDS}", ("observer",))
    rho = 1.0 if decay_rate is None else float(decay_rate)
    if not 0.0 < rho <= 1.0:
        raise InvalidInput("the observer's decay_rate must be in (0, 1]", ("decay_rate",))
    F = np.asarray(family.F, dtype=np.float64)
    r, n, p = family.n_modes, family.n_states, C.shape[1]
    if noise is not None:
        Lk = kalman_gains(family, noise)
        if kind == "common" and r > 1 and not np.allclose(Lk, Lk[:1]):
            Lk = None
        if Lk is not None:
            Q = certify_observer(family, Lk, M, decay_rate, time_limit)
            if Q is not None:
                return ObserverDesign("certified", Lk, Q, decay_rate, "kalman",
                                      "the steady-state Kalman gains, certified for the sensor losses",
                                      error_bound=error_covariance_bound(family, Lk, M, noise, time_limit))
    obstruction = observer_obstruction(family, M)
    if obstruction is not None:
        return ObserverDesign("no_observer", None, None, None, kind,
                              f"no observer gain exists: with {M - 1} measurements lost then one received, "
                              f"plant mode {obstruction.mode} has an unobservable mode of modulus "
                              f"{abs(obstruction.eigenvalue):.6g} >= 1", obstruction)
    Q = [cp.Variable((n, n), symmetric=True) for _ in range(M)]
    Y = [cp.Variable((n, p))] * r if kind == "common" else [cp.Variable((n, p)) for _ in range(r)]
    t = cp.Variable()
    cons = [sum(cp.trace(q) for q in Q) == M * n]
    cons += [q >> t * np.eye(n) for q in Q]
    for l, l_next in itertools.product(range(r), repeat=2):
        for sigma in range(M):
            lower = (Q[0] - Y[l_next] @ C[l_next]) @ F[l]
            blk = cp.bmat([[rho**2 * Q[sigma], lower.T], [lower, Q[0]]])
            cons.append(0.5 * (blk + blk.T) >> t * np.eye(2 * n))
            if sigma + 1 <= M - 1:
                loss = rho**2 * Q[sigma] - F[l].T @ Q[sigma + 1] @ F[l]
                cons.append(0.5 * (loss + loss.T) >> t * np.eye(n))
    prob = cp.Problem(cp.Maximize(t), cons)
    status = _solve(prob, time_limit)
    if t.value is None or Q[0].value is None:
        return ObserverDesign("not_certified", None, None, None, kind,
                              f"the observer LMI was not solved (CLARABEL status {status})")
    if t.value <= 0:
        return ObserverDesign("not_certified", None, None, None, kind,
                              f"the sufficient observer LMI has no strictly feasible point (optimum "
                              f"{float(t.value):.3g} <= 0 per CLARABEL, not a proof that no gain exists)")
    Q0 = 0.5 * (Q[0].value + Q[0].value.T)
    L = np.array([np.linalg.solve(Q0, Y[l].value) for l in range(r)])
    Qv = certify_observer(family, L, M, decay_rate, time_limit)
    if Qv is None:
        return ObserverDesign("not_certified", L, None, None, kind,
                              "the observer gains from the LMI did not pass the float64 re-check")
    bound = None if noise is None else error_covariance_bound(family, L, M, noise, time_limit)
    return ObserverDesign("certified", L, Qv, decay_rate, kind, "observer certified", error_bound=bound)


# ------------------------------------------------------------------ the joint certificate
@dataclass
class JointCertificate:
    """``V = x' P x + e' Q_sigma e`` for the whole loop (plant, estimate, buffer), re-checked.

    Attributes
    ----------
    P : ndarray, shape (n, n)
    Q : ndarray, shape (sensor_n_drop, n, n)
    blocks : int
        Interval x sensor-pattern x next-mode inequalities checked.
    worst : float
        Largest proven upper bound of ``lambda_max`` over the decrease conditions (negative).
    """

    P: np.ndarray
    Q: np.ndarray
    blocks: int
    worst: float
    checked: bool = True
    kind: str = "joint_block_diagonal"

    def to_dict(self) -> dict:
        return {"kind": self.kind, "P": self.P.tolist(), "Q": self.Q.tolist(), "blocks": self.blocks,
                "worst": self.worst, "checked": self.checked}


def joint_blocks(family: PlantFamily, gains, n_drop: int, observer_gains, sensor_n_drop: int,
                 plant_switching: str = "per_interval", scheme: str = "predictive"):
    """Every joint interval map ``[[A_s, -B_s], [0, E]]`` with its sensor nodes ``(from, to)``.

    Raises InvalidInput when their number exceeds :data:`MAX_JOINT_BLOCKS`.
    """
    C = require_outputs(family)
    M = check_sensor_n_drop(sensor_n_drop)
    modes = ModeSet.from_family(family, n_drop, plant_switching=plant_switching, scheme=scheme)
    K = check_gains(gains, modes.n_drop, family.n_inputs, family.n_states)
    L = check_observer_gains(observer_gains, family.n_modes, family.n_states, C.shape[1])
    F = np.asarray(family.F, dtype=np.float64)
    r, n = family.n_modes, family.n_states
    A = modes.closed_loops(K)
    B = A - modes.free
    count = sum(r * sum(1 for sigma in range(M) for _ in sensor_runs(int(eta), sigma, M)) for eta in modes.eta)
    if count > MAX_JOINT_BLOCKS:
        raise InvalidInput(f"the joint certificate needs {count} interval x sensor-pattern inequalities (limit "
                           f"{MAX_JOINT_BLOCKS}): lower n_drop or sensor_n_drop", ("sensor_n_drop",))
    out = []
    for s in range(modes.n_modes):
        eta = int(modes.eta[s])
        for l_next in range(r):
            for sigma in range(M):
                for arrivals, end in sensor_runs(eta, sigma, M):
                    E = error_map(F, C, L, modes.plants[s], l_next, arrivals)
                    J = np.zeros((2 * n, 2 * n))
                    J[:n, :n] = A[s]
                    J[:n, n:] = -B[s]
                    J[n:, n:] = E
                    out.append((J, sigma, end))
    return out


def check_joint(blocks, P: np.ndarray, Q: np.ndarray) -> tuple[bool, float]:
    """Float64 re-check of ``J' diag(P, Q_to) J - diag(P, Q_from) < 0`` for every block (no solver)."""
    prover = Prover()
    if prover.min_lower(P) <= 0 or any(prover.min_lower(q) <= 0 for q in Q):
        return False, np.inf
    n = P.shape[0]
    worst = -np.inf
    for J, frm, to in blocks:
        D_to = np.zeros((2 * n, 2 * n))
        D_to[:n, :n], D_to[n:, n:] = P, Q[to]
        D_from = np.zeros((2 * n, 2 * n))
        D_from[:n, :n], D_from[n:, n:] = P, Q[frm]
        Mat = J.T @ D_to @ J - D_from
        scale = float(np.linalg.norm(J) ** 2 * np.linalg.norm(D_to) + np.linalg.norm(D_from))
        bound = _upper_with_rounding(Mat, scale, prover)
        worst = max(worst, bound)
        if bound >= 0:
            return False, worst
    return True, float(worst)


def joint_certificate(family: PlantFamily, gains, n_drop: int, observer_gains, sensor_n_drop: int, *,
                      plant_switching: str = "per_interval", scheme: str = "predictive",
                      time_limit: float | None = None) -> JointCertificate | None:
    """One quadratic certificate for the whole output-feedback loop, or None when the LMI finds none.

    Solves, with Clarabel, ``max t`` over ``P``, ``Q_sigma`` (``trace`` normalized) subject to
    ``diag(P, Q_from) - J' diag(P, Q_to) J >= t I`` for every block of :func:`joint_blocks`; the result
    counts only after :func:`check_joint`.
    """
    import cvxpy as cp

    blocks = joint_blocks(family, gains, n_drop, observer_gains, sensor_n_drop, plant_switching, scheme)
    n = family.n_states
    M = check_sensor_n_drop(sensor_n_drop)
    P = cp.Variable((n, n), symmetric=True)
    Q = [cp.Variable((n, n), symmetric=True) for _ in range(M)]
    t = cp.Variable()
    cons = [cp.trace(P) + sum(cp.trace(q) for q in Q) == (M + 1) * n, P >> t * np.eye(n)]
    cons += [q >> t * np.eye(n) for q in Q]
    for J, frm, to in blocks:
        Jtop, Jbot = J[:n], J[n:]  # the rows giving x and e at the interval's end
        quad = Jtop.T @ P @ Jtop + Jbot.T @ Q[to] @ Jbot
        D = cp.bmat([[P, np.zeros((n, n))], [np.zeros((n, n)), Q[frm]]])
        blk = D - quad
        cons.append(0.5 * (blk + blk.T) >> t * np.eye(2 * n))
    prob = cp.Problem(cp.Maximize(t), cons)
    _solve(prob, time_limit)
    if t.value is None or P.value is None or t.value <= 0:
        return None
    Pv = 0.5 * (P.value + P.value.T)
    Qv = np.array([0.5 * (q.value + q.value.T) for q in Q])
    ok, worst = check_joint(blocks, Pv, Qv)
    return JointCertificate(Pv, Qv, len(blocks), worst) if ok else None


# ------------------------------------------------------------------ analysis of given K and L
@dataclass
class OutputAnalysis:
    """Verdict on the whole output-feedback loop for given ``K`` and ``L``.

    ``stable`` True with ``certificate`` (:class:`JointCertificate`); False with ``reason`` naming the
    proof (the full-state loop's unstable product, which the output loop runs from ``xh(0) = x(0)``, or
    an admissible periodic sensor pattern whose error map has spectral radius > 1); None otherwise.
    """

    stable: bool | None
    reason: str
    certificate: JointCertificate | None = None
    state_feedback: object | None = None
    error_cycle: dict | None = None
    error_certificate: np.ndarray | None = None

    def to_dict(self) -> dict:
        return {"stable": self.stable, "reason": self.reason,
                "certificate": None if self.certificate is None else self.certificate.to_dict(),
                "error_cycle": self.error_cycle}


def unstable_error_cycle(family: PlantFamily, observer_gains, sensor_n_drop: int, max_length: int = 6,
                         margin: float = 1e-6) -> dict | None:
    """An admissible periodic sensor pattern (one plant mode) whose error map has ``rho >= 1 + margin``."""
    C = require_outputs(family)
    M = check_sensor_n_drop(sensor_n_drop)
    L = check_observer_gains(observer_gains, family.n_modes, family.n_states, C.shape[1])
    F = np.asarray(family.F, dtype=np.float64)
    best = None
    for l in range(family.n_modes):
        for length in range(1, max_length + 1):
            for bits in itertools.product((True, False), repeat=length):
                # Periodic and admissible: the longest run of losses, wrapping around, is at most M - 1.
                doubled = bits + bits
                run = longest = 0
                for got in doubled:
                    run = 0 if got else run + 1
                    longest = max(longest, run)
                if not any(bits) or longest > M - 1:
                    continue
                E = error_map(F, C, L, (l,) * length, l, bits)
                rho = float(np.max(np.abs(np.linalg.eigvals(E)))) ** (1.0 / length)
                if rho >= 1.0 + margin and (best is None or rho > best["rate"]):
                    best = {"plant": l, "arrivals": [bool(b) for b in bits], "rate": rho}
    return best


def analyze_output(family: PlantFamily, gains, n_drop: int, observer_gains, sensor_n_drop: int, *,
                   plant_switching: str = "per_interval", scheme: str = "predictive",
                   state_report=None) -> OutputAnalysis:
    """Stability of the output-feedback loop with given ``K`` and ``L`` (see :class:`OutputAnalysis`)."""
    if state_report is not None and state_report.stable is False:
        return OutputAnalysis(False, "the full-state loop with these gains is unstable (its proof applies: "
                                     "from xh(0) = x(0) the output loop runs it exactly)",
                              state_feedback=state_report)
    cycle = unstable_error_cycle(family, observer_gains, sensor_n_drop)
    if cycle is not None:
        return OutputAnalysis(False, f"the estimate diverges: plant mode {cycle['plant']} with the periodic "
                                     f"sensor pattern {cycle['arrivals']} grows the error by {cycle['rate']:.6g} "
                                     "per sample", state_feedback=state_report, error_cycle=cycle)
    cert = joint_certificate(family, gains, n_drop, observer_gains, sensor_n_drop,
                             plant_switching=plant_switching, scheme=scheme)
    if cert is not None:
        return OutputAnalysis(True, "joint quadratic certificate (plant, estimate, buffer) re-checked in float64",
                              cert, state_report)
    return OutputAnalysis(None, "no joint certificate found and no destabilizing pattern proven",
                          state_feedback=state_report)


# ------------------------------------------------------------------ LQG (no losses)
def lqg_cost(family: PlantFamily, gains, observer_gains, weights, noise, mode: int = 0) -> float:
    """Stationary ``E[x' Q x + u' R u]`` per sample of one plant mode without losses (n_drop = 1).

    From the joint covariance of ``(x, e)``: ``x+ = (F + G K) x - G K e + w``,
    ``e+ = (I - L C)(F e + w) - L v`` (the discrete Lyapunov equation of that loop).
    """
    from scipy.linalg import solve_discrete_lyapunov

    C = require_outputs(family)
    n, m, p = family.n_states, family.n_inputs, C.shape[1]
    K = check_gains(gains, 1, m, n)[0]
    L = check_observer_gains(observer_gains, family.n_modes, n, p)[mode]
    W, V = check_noise(noise, n, p)
    Qw, Rw = (np.asarray(M, dtype=np.float64) for M in weights)
    F, G, Cl = family.F[mode], family.G[mode], C[mode]
    I = np.eye(n)
    A = np.block([[F + G @ K, -G @ K], [np.zeros((n, n)), (I - L @ Cl) @ F]])
    Bw = np.vstack([I, I - L @ Cl])
    Bv = np.vstack([np.zeros((n, p)), -L])
    S = solve_discrete_lyapunov(A, Bw @ W @ Bw.T + Bv @ V @ Bv.T)
    Kx = np.hstack([K, -K])
    return float(np.trace(Qw @ S[:n, :n]) + np.trace(Rw @ Kx @ S @ Kx.T))


# ------------------------------------------------------------------ simulation
def simulate_output(family: PlantFamily, K: np.ndarray, n_drop: int, L, x0: np.ndarray, steps: int, seed: int,
                    *, sensor_n_drop: int, sensor_loss: float, control_loss: float, xh0=None,
                    plant_switching: str = "per_interval", mode: int | None = None,
                    switch_probability: float = 1.0):
    """Seeded run of the output-feedback loop (see the module docstring); returns a SimulationResult.

    Per sample: the measurement arrives with probability ``1 - sensor_loss`` (forced after
    ``sensor_n_drop - 1`` losses in a row), the control packet with ``1 - control_loss`` (forced after
    ``n_drop - 1``); sample 0 delivers both.  ``tr.estimate[k]`` is ``xh(k|k)`` (the last row ``xh(steps|steps-1)``),
    ``tr.sensor_arrived`` the measurements, ``tr.control_arrived`` (= ``effective``) the packets.
    """
    from .simulate import SimulationResult

    C = require_outputs(family)
    M = check_sensor_n_drop(sensor_n_drop)
    n, m, r = family.n_states, family.n_inputs, family.n_modes
    L = check_observer_gains(L, r, n, C.shape[1])
    if plant_switching not in PLANT_SWITCHING:
        raise InvalidInput(f"plant_switching must be one of {PLANT_SWITCHING}", ("plant_switching",))
    if xh0 is None:
        xh = np.zeros(n)
    else:
        try:
            xh = np.array(xh0, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise InvalidInput("xh0 must be a list of numbers", ("xh0",)) from None
        if xh.shape != (n,) or not np.all(np.isfinite(xh)):
            raise InvalidInput(f"xh0 must hold {n} finite numbers", ("xh0",))
    rng = np.random.Generator(np.random.PCG64(int(seed)))
    draw_sensor = rng.random(steps)
    draw_control = rng.random(steps)
    draw_switch = rng.random(steps)
    draw_mode = rng.integers(0, r, size=steps)
    current = int(rng.integers(0, r)) if mode is None else int(mode)

    state = np.empty((steps + 1, n))
    estimate = np.empty((steps + 1, n))
    inputs = np.empty((steps, m))
    modes = np.empty(steps, dtype=np.int64)
    sensor = np.empty(steps, dtype=bool)
    control = np.empty(steps, dtype=bool)
    qs = np.empty(steps, dtype=np.int64)
    x = np.array(x0, dtype=np.float64)
    state[0] = x
    buffer = None
    q = 0
    sensor_row = control_row = 0
    for k in range(steps):
        got_u = k == 0 or draw_control[k] >= control_loss or control_row >= n_drop - 1
        control_row = 0 if got_u else control_row + 1
        jump = {"per_sample": True, "per_interval": got_u, "none": False}[plant_switching]
        if k > 0 and jump and draw_switch[k] < switch_probability:
            current = int(draw_mode[k])
        got_y = k == 0 or draw_sensor[k] >= sensor_loss or sensor_row >= M - 1
        sensor_row = 0 if got_y else sensor_row + 1
        if got_y:
            Cl = C[current]
            xh = xh + L[current] @ (Cl @ x - Cl @ xh)
        if got_u:
            buffer = K @ xh  # (n_drop, m)
            q = 1
        else:
            q += 1
        u = buffer[min(q, n_drop) - 1]
        estimate[k] = xh
        modes[k] = current
        sensor[k], control[k], qs[k] = got_y, got_u, q
        inputs[k] = u
        x = family.F[current] @ x + family.G[current] @ u
        xh = family.F[current] @ xh + family.G[current] @ u
        state[k + 1] = x
    estimate[steps] = xh
    starts = np.flatnonzero(control)
    h = family.sampling_period
    time_axis = np.arange(steps + 1) * (h if h is not None else 1.0)
    return SimulationResult(time=time_axis, state=state, input=inputs, mode=modes, sensor_arrived=sensor,
                            control_arrived=control, effective=control.copy(), buffer_index=qs,
                            interval_start=starts, eta=np.diff(starts), seed=int(seed), loss_model="bernoulli",
                            plant_switching=plant_switching, n_drop=n_drop, estimate=estimate)


# ------------------------------------------------------------------ design(feedback="output")
def prepare_output_design(family: PlantFamily, n_drop, sensor_n_drop, observer: str, noise) -> int:
    """Validate the output-feedback options before anything is solved; returns ``sensor_n_drop``."""
    C = require_outputs(family)
    check_n_drop(n_drop)
    M = check_sensor_n_drop(n_drop if sensor_n_drop is None else sensor_n_drop)
    if observer not in OBSERVER_KINDS:
        raise InvalidInput(f"observer must be one of {OBSERVER_KINDS}, got {observer!r}", ("observer",))
    if noise is not None:
        check_noise(noise, family.n_states, C.shape[1])
    return M


def complete_output_design(res, family: PlantFamily, sensor_n_drop: int, observer: str, noise,
                           plant_switching: str, scheme: str, time_limit: float | None):
    """Turn a full-state design into the output-feedback one: observer gains, joint certificate, verdict.

    The verdict words (docs/design.md, "Output feedback"): "infeasible" when the full-state design has a
    proof that no K exists (from ``xh(0) = x(0)`` the output loop runs the full-state loop exactly, so
    the proof applies) or when :func:`observer_obstruction` proves no observer gain exists;
    "not_certified" when the observer LMI or the joint LMI found nothing (no proof of impossibility);
    "stabilized" only with a :class:`JointCertificate` that passed :func:`check_joint`.
    """
    res.feedback = "output"
    if res.outcome != "stabilized":
        why = {"infeasible": "its proof applies to output feedback too (from xh(0) = x(0) the output loop is "
                             "the full-state loop)"}.get(res.outcome, "no observer was designed")
        res.message = f"the full-state design is {res.outcome}: {why}. {res.message}".strip()
        return res
    obs = design_observer(family, sensor_n_drop, kind=observer, noise=noise, time_limit=time_limit)
    res.observer = obs
    state_rate = res.decay_rate
    # The certified rate and settling time were the full-state loop's; the joint certificate proves stability.
    res.decay_rate = None
    res.settling = None
    if obs.outcome == "no_observer":
        res.outcome = "infeasible"
        res.message = f"{obs.message} (res.observer.obstruction); the full-state gains K are certified"
        return res
    if obs.outcome != "certified":
        res.outcome = "not_certified"
        res.message = f"the full-state gains are certified; the observer is not: {obs.message}"
        return res
    res.observer_gains = obs.gains
    joint = joint_certificate(family, res.gains, res.n_drop, obs.gains, sensor_n_drop,
                              plant_switching=plant_switching, scheme=scheme, time_limit=time_limit)
    if joint is None:
        res.outcome = "not_certified"
        res.message = ("K and L are each certified, but no joint quadratic certificate for the whole loop "
                       "passed the float64 re-check")
        return res
    res.joint_certificate = joint
    rate = "" if state_rate is None else f"; the full-state loop's certified rate was {state_rate:.4g} per sample"
    res.message = (f"output feedback certified: {joint.blocks} joint interval inequalities (plant, estimate, buffer) "
                   f"re-checked in float64, sensor_n_drop = {sensor_n_drop}{rate}")
    return res


# ------------------------------------------------------------------ Bernoulli sensor link
def error_second_moment_radius(family: PlantFamily, observer_gains, arrival: float, mode: int = 0) -> float:
    """Spectral radius of the filtered error's second-moment map under i.i.d. arrivals (one plant mode).

    ``E[e e']`` evolves by ``S -> a Phi S Phi' + (1 - a) F S F'`` with ``Phi = (I - L C) F`` and arrival
    probability ``a``; the error is mean-square stable iff the radius of
    ``a Phi (x) Phi + (1 - a) F (x) F`` is below 1 (Kronecker form of that map).
    """
    C = require_outputs(family)
    L = check_observer_gains(observer_gains, family.n_modes, family.n_states, C.shape[1])[mode]
    if not 0.0 <= float(arrival) <= 1.0:
        raise InvalidInput("arrival must be a probability in [0, 1]", ("arrival",))
    F = np.asarray(family.F[mode], dtype=np.float64)
    Phi = (np.eye(family.n_states) - L @ C[mode]) @ F
    T = arrival * np.kron(Phi, Phi) + (1.0 - arrival) * np.kron(F, F)
    return float(np.max(np.abs(np.linalg.eigvals(T))))


def critical_arrival(family: PlantFamily, observer_gains, mode: int = 0, tol: float = 1e-10) -> float:
    """Smallest measurement arrival probability at which the error stays mean-square bounded (bisection).

    The radius of :func:`error_second_moment_radius` is affine-in-``a`` operator's, monotone for the gains
    where the measured step contracts more than the open loop; returns 0 when the error is stable without
    measurements and 1 when it is not even with all of them.
    """
    if error_second_moment_radius(family, observer_gains, 0.0, mode) < 1.0:
        return 0.0
    if error_second_moment_radius(family, observer_gains, 1.0, mode) >= 1.0:
        return 1.0
    lo, hi = 0.0, 1.0
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if error_second_moment_radius(family, observer_gains, mid, mode) < 1.0:
            hi = mid
        else:
            lo = mid
    return hi


# ------------------------------------------------------------------ stochastic links on both sides
@dataclass
class OutputChannelReport:
    """The output-feedback loop on Markov sensor and control channels (:func:`analyze_output_channel`).

    Attributes
    ----------
    ms_radius : float
        Spectral radius of the second-moment operator of the jump linear system on ``(x, e, s)``.
    ms_stable : bool or None
        True only with a re-checked certificate: ``Y_theta > 0`` with ``Y - T(Y) > 0`` blockwise (``T`` maps PSD
        to PSD, so this proves ``ms_radius < 1``), checked in float64 with proven Cholesky bounds; False when the
        float64 radius is ``>= 1 + 1e-6``; None otherwise.
    stationary_cost : float or None
        With ``noise`` and when mean-square stable: the long-run ``E[x'Qx + u'Ru]`` per sample.
    estimation_error : ndarray (n, n) or None
        The stationary ``E[e e']`` of the filtered error (with ``noise``).
    """

    ms_radius: float
    ms_stable: bool | None
    stationary_cost: float | None
    estimation_error: np.ndarray | None
    exhausted: str
    states: int

    def to_dict(self) -> dict:
        return {"ms_radius": self.ms_radius, "ms_stable": self.ms_stable, "stationary_cost": self.stationary_cost,
                "estimation_error": None if self.estimation_error is None else self.estimation_error.tolist(),
                "exhausted": self.exhausted, "states": self.states}


#: Largest second-moment operator (unknowns) :func:`analyze_output_channel` builds densely.
MAX_OUTPUT_CHANNEL_SIZE = 4000


def _output_channel_maps(family, K, L, C, n_drop, exhausted, mode):
    """Per (sensor arrival g, control delivery c, new age d): the maps of z = (x, e_pred, s).

    Returns a dict (g, c, d) -> (A, Bw, Bv, U, Uv, Ef, Efv): ``z+ = A z + Bw w + Bv v``, ``u = U z + Uv v``,
    the filtered error ``e_f = Ef z + Efv v``.
    """
    n, m, p = family.n_states, family.n_inputs, C.shape[1]
    F, G, Cl, Ll = family.F[mode], family.G[mode], C[mode], L[mode]
    I, Z = np.eye(n), np.zeros((n, n))
    out = {}
    for g, c, d in itertools.product((0, 1), (0, 1), range(n_drop + 1)):
        if c and d != 0 or not c and d == 0:
            continue
        Ef = np.hstack([Z, I - g * Ll @ Cl, Z])
        Efv = -g * Ll
        Sel = np.hstack([I, -(I - g * Ll @ Cl), Z]) if c else np.hstack([Z, Z, I])  # s_new = x - e_f, or s
        Selv = g * Ll if c else np.zeros((n, p))
        if d < n_drop:
            Kd = K[d]
        else:
            Kd = K[n_drop - 1] if exhausted == "hold" else np.zeros((m, n))
        U, Uv = Kd @ Sel, Kd @ Selv
        A = np.vstack([np.hstack([F, Z, Z]) + G @ U, F @ Ef, Sel])
        Bw = np.vstack([I, I, Z])
        Bv = np.vstack([G @ Uv, F @ Efv, Selv])
        out[(g, c, d)] = (A, Bw, Bv, U, Uv, Ef, Efv)
    return out


def _ms_certificate(T: np.ndarray, count: int, side: int) -> bool:
    """``Y = (I - T)^-1 vec(I, ..., I)``: True when every ``Y_theta`` and ``Y_theta - T(Y)_theta`` is proven PD."""
    blk = side * side
    eye = np.tile(np.eye(side).reshape(-1, order="F"), count)
    try:
        Y = np.linalg.solve(np.eye(T.shape[0]) - T, eye)
    except np.linalg.LinAlgError:
        return False
    R = Y - T @ Y
    prover = Prover()
    for k in range(count):
        Yk = Y[k * blk:(k + 1) * blk].reshape(side, side, order="F")
        Rk = R[k * blk:(k + 1) * blk].reshape(side, side, order="F")
        # T @ Y has rounding errors of about the size of its inputs: count them against R's margin.
        err = 4 * (T.shape[0] + 2) * U * float(np.abs(T[k * blk:(k + 1) * blk]).sum(axis=1).max() *
                                               np.abs(Y).max() * side + np.abs(Yk).max() * side)
        if prover.min_lower(0.5 * (Yk + Yk.T)) <= 0 or prover.min_lower(0.5 * (Rk + Rk.T), err) <= 0:
            return False
    return True


def analyze_output_channel(family: PlantFamily, gains, n_drop: int, observer_gains, sensor_channel,
                           control_channel, *, exhausted: str = "hold", weights=None, noise=None,
                           mode: int | None = None) -> OutputChannelReport:
    """Mean-square stability and the stationary cost of output feedback on two Markov channels, exactly.

    Per sample (the loop of :func:`simulate_output`, plant mode ``mode`` fixed): the measurement arrives
    with probability ``1 - sensor_channel.loss[cs]``, the control packet with ``1 - control_channel.loss[cc]``,
    independently; the buffer plays ``K_{d+1}`` of the last delivered estimate, then the ``exhausted`` policy;
    ``x+ = F x + G u + w``, ``y = C x + v``.  The jump linear system on ``z = (x, e, s)`` (state, predicted
    error, the delivered estimate) with discrete state (sensor channel state, control channel state, age)
    has the second-moment operator whose radius decides mean-square stability, and whose fixed point with the
    noise terms gives the stationary cost (docs/design.md §12).  ``mode=None``: the plant mode is drawn
    uniformly once and kept (as :func:`solver.analyze_channel` without ``plant_transitions``): stable when
    every mode is, the cost is the mean over modes.
    """
    from .channel import Channel

    if mode is None:
        reports = [analyze_output_channel(family, gains, n_drop, observer_gains, sensor_channel, control_channel,
                                          exhausted=exhausted, weights=weights, noise=noise, mode=l)
                   for l in range(family.n_modes)]
        verdicts = [rep.ms_stable for rep in reports]
        stable = False if False in verdicts else True if all(v is True for v in verdicts) else None
        costs = [rep.stationary_cost for rep in reports]
        cost = float(np.mean(costs)) if stable and all(c is not None for c in costs) else None
        err = np.mean([rep.estimation_error for rep in reports], axis=0) if cost is not None else None
        return OutputChannelReport(max(rep.ms_radius for rep in reports), stable, cost, err, exhausted,
                                   reports[0].states)

    C = require_outputs(family)
    n_drop = check_n_drop(n_drop)
    K = check_gains(gains, n_drop, family.n_inputs, family.n_states)
    n, m, p = family.n_states, family.n_inputs, C.shape[1]
    L = check_observer_gains(observer_gains, family.n_modes, n, p)
    for name, ch in (("sensor_channel", sensor_channel), ("control_channel", control_channel)):
        if not isinstance(ch, Channel):
            raise InvalidInput(f"{name} must be a solver.Channel (e.g. Channel.bernoulli(0.2))", (name,))
    if exhausted not in ("hold", "zero"):
        raise InvalidInput("exhausted must be 'hold' or 'zero'", ("exhausted",))
    if isinstance(mode, bool) or not isinstance(mode, (int, np.integer)) or not 0 <= mode < family.n_modes:
        raise InvalidInput(f"mode must be an integer in 0..{family.n_modes - 1}", ("mode",))
    Ts, ls = np.asarray(sensor_channel.transition), np.asarray(sensor_channel.loss)
    Tc, lc = np.asarray(control_channel.transition), np.asarray(control_channel.loss)
    thetas = list(itertools.product(range(len(ls)), range(len(lc)), range(n_drop + 1)))
    index = {t: i for i, t in enumerate(thetas)}
    N3 = 3 * n
    size = len(thetas) * N3 * N3
    if size > MAX_OUTPUT_CHANNEL_SIZE:
        raise InvalidInput(f"the second-moment operator has {size} unknowns (limit {MAX_OUTPUT_CHANNEL_SIZE}): "
                           "use channels with fewer states or a smaller n_drop", ("sensor_channel",))
    maps = _output_channel_maps(family, K, L, C, n_drop, exhausted, int(mode))
    # Transition weights: from theta = (cs, cc, d_prev) through (g, c) to theta' = (cs', cc', d).
    moves = []
    for (cs, cc, dp) in thetas:
        for g, c in itertools.product((0, 1), (0, 1)):
            pg = (1.0 - ls[cs]) if g else ls[cs]
            pc = (1.0 - lc[cc]) if c else lc[cc]
            if pg == 0.0 or pc == 0.0:
                continue
            d = 0 if c else min(dp + 1, n_drop)
            for cs2, cc2 in itertools.product(range(len(ls)), range(len(lc))):
                w = pg * pc * Ts[cs, cs2] * Tc[cc, cc2]
                if w > 0.0:
                    moves.append((index[(cs, cc, dp)], index[(cs2, cc2, d)], w, g, c, d))
    # The operator on vec(X_theta), column-major vec: vec(A X A') = (A kron A) vec(X).
    T = np.zeros((size, size))
    blk = N3 * N3
    for i, j, w, g, c, d in moves:
        A = maps[(g, c, d)][0]
        T[j * blk:(j + 1) * blk, i * blk:(i + 1) * blk] += w * np.kron(A, A)
    radius = float(np.max(np.abs(np.linalg.eigvals(T))))
    stable = False if radius >= 1 + 1e-6 else None
    if radius < 1:
        stable = _ms_certificate(T, len(thetas), N3) or None
    cost = err = None
    if noise is not None and stable:
        W, V = check_noise(noise, n, p)
        Qw, Rw = (np.eye(n), np.eye(m)) if weights is None else (np.asarray(weights[0], float),
                                                                 np.asarray(weights[1], float))
        # Stationary distribution of theta (the chain of the moves), then the noise injected per move.
        Pm = np.zeros((len(thetas), len(thetas)))
        for i, j, w, *_ in moves:
            Pm[i, j] += w
        vals, vecs = np.linalg.eig(Pm.T)
        pi = np.real(vecs[:, int(np.argmin(np.abs(vals - 1.0)))])
        pi = pi / pi.sum()
        inject = np.zeros(size)
        for i, j, w, g, c, d in moves:
            _, Bw, Bv, *_ = maps[(g, c, d)]
            inject[j * blk:(j + 1) * blk] += pi[i] * w * (Bw @ W @ Bw.T + Bv @ V @ Bv.T).reshape(-1, order="F")
        X = np.linalg.solve(np.eye(size) - T, inject)
        cost = 0.0
        err = np.zeros((n, n))
        for i, j, w, g, c, d in moves:
            _, _, _, U, Uv, Ef, Efv = maps[(g, c, d)]
            Xi = X[i * blk:(i + 1) * blk].reshape(N3, N3, order="F")
            cost += w * (np.trace(Qw @ Xi[:n, :n]) + np.trace(Rw @ U @ Xi @ U.T)
                         + pi[i] * np.trace(Rw @ Uv @ V @ Uv.T))
            err += w * (Ef @ Xi @ Ef.T + pi[i] * Efv @ V @ Efv.T)
        cost = float(cost)
    return OutputChannelReport(radius, stable, cost, err, exhausted, len(thetas))
