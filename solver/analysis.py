"""Stability analysis of given predictive gains: ``analyze(family, gains, n_drop)``.

Three verdicts, each with its evidence:

* ``stable=True``: a Theorem 1 certificate P (found by an LMI in P for the
  fixed gains) that passed the float64 ``eigvalsh`` re-check;
* ``stable=False``: a mode, or a finite product of modes (a concrete pattern
  of losses and plant jumps repeated forever), whose spectral radius is >= 1;
* ``stable=None``: neither could be shown.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .compiled import check_solver
from .errors import InvalidInput, SolverFailed
from .lyapunov import Certificate, lift, recheck, theorem1_lmi
from .network import IntervalData, check_gains, check_n_drop, closed_loop_matrices, mode_list, spectral_radii
from .plant import PlantFamily


@dataclass
class AnalysisReport:
    """Result of :func:`analyze`.

    Attributes
    ----------
    stable : bool or None
    spectral_radii : ndarray, shape (r, n_drop)
        Spectral radius of ``A_{l,eta}(K)`` for every mode.
    max_spectral_radius : float
    certificate : Certificate or None
        Re-checked Theorem 1 certificate when ``stable`` is True.
    margin : float or None
        The certificate's relative margin ``min_s lambda_min(P - Phi_s^T P Phi_s) / lambda_max(P)``.
    jsr_lower_bound : float
        ``max rho(product)^(1/length)`` over all products of modes up to
        ``product_length_checked``: a lower bound of the joint spectral radius
        per interval.
    worst_sequence : list of (l, eta)
        The product attaining ``jsr_lower_bound``, in the order applied; when
        ``stable`` is False, repeating it forever makes the loop diverge (or
        not decay).
    product_length_checked : int
    reason : str
    timings : dict
    """

    stable: bool | None
    spectral_radii: np.ndarray
    certificate: Certificate | None
    jsr_lower_bound: float
    worst_sequence: list
    product_length_checked: int
    reason: str
    timings: dict = field(default_factory=dict)

    @property
    def max_spectral_radius(self) -> float:
        return float(np.max(self.spectral_radii))

    @property
    def margin(self) -> float | None:
        return None if self.certificate is None else self.certificate.margin

    def to_dict(self) -> dict:
        return {
            "stable": self.stable,
            "reason": self.reason,
            "spectral_radii": self.spectral_radii.tolist(),
            "max_spectral_radius": self.max_spectral_radius,
            "margin": self.margin,
            "certificate": None if self.certificate is None else self.certificate.to_dict(),
            "jsr_lower_bound": self.jsr_lower_bound,
            "worst_sequence": [{"plant": l, "eta": eta} for l, eta in self.worst_sequence],
            "product_length_checked": self.product_length_checked,
            "timings": self.timings,
        }


def product_lower_bound(A_modes: np.ndarray, max_length: int, max_products: int) -> tuple[float, tuple, int]:
    """Largest ``rho(A_{s_k} ... A_{s_1})^(1/k)`` over all mode sequences up to a length.

    Parameters
    ----------
    A_modes : ndarray, shape (S, n, n)
    max_length : int
        Longest product tried.
    max_products : int
        Budget of products per length; longer lengths that exceed it are skipped.

    Returns
    -------
    bound : float
    sequence : tuple of int
        Mode indices in the order applied.
    length_checked : int
    """
    S = A_modes.shape[0]
    rho = np.max(np.abs(np.linalg.eigvals(A_modes)), axis=-1)
    best = int(np.argmax(rho))
    bound, sequence = float(rho[best]), (best,)
    products = A_modes
    checked = 1
    for k in range(2, max_length + 1):
        if products.shape[0] * S > max_products:
            break
        # products[i] applies sequence i (base-S digits, first applied most significant);
        # extend every sequence by one more mode applied last.
        products = np.einsum("jab,ibc->ijac", A_modes, products).reshape(-1, *A_modes.shape[1:])
        checked = k
        rho_k = np.max(np.abs(np.linalg.eigvals(products)), axis=-1) ** (1.0 / k)
        i = int(np.argmax(rho_k))
        if rho_k[i] > bound * (1 + 1e-12):
            bound = float(rho_k[i])
            sequence = tuple(int(d) for d in np.unravel_index(i, (S,) * k))
    return bound, sequence, checked


def analyze(
    family: PlantFamily,
    gains,
    n_drop: int,
    *,
    max_product_length: int = 4,
    max_products: int = 100_000,
    solver: str = "CLARABEL",
) -> AnalysisReport:
    """Decide stability of the networked loop with given gains under arbitrary losses and jumps.

    Parameters
    ----------
    family : PlantFamily
    gains : array_like, shape (n_drop, m, n)
        ``gains[q-1] = K_q`` (for m = 1 also (n_drop, n)).
    n_drop : int
    max_product_length : int
        Longest product of modes searched for a destabilizing pattern.
    max_products : int
        Budget of products per length (bounds time and memory).
    solver : {"CLARABEL", "SCS"}

    Returns
    -------
    AnalysisReport
    """
    start = time.perf_counter()
    if not isinstance(family, PlantFamily):
        raise InvalidInput("family must be a PlantFamily", ("family",))
    n_drop = check_n_drop(n_drop)
    K = check_gains(gains, n_drop, family.n_inputs, family.n_states)
    if isinstance(max_product_length, bool) or not isinstance(max_product_length, (int, np.integer)) or not (
        1 <= max_product_length <= 12
    ):
        raise InvalidInput("max_product_length must be an integer in 1..12", ("max_product_length",))
    solver = check_solver(solver)
    data = IntervalData.from_family(family, n_drop)
    A = closed_loop_matrices(data, K)
    radii = spectral_radii(A)
    modes = mode_list(family.n_modes, n_drop)
    A_modes = A.reshape(-1, family.n_states, family.n_states)
    bound, seq, checked = product_lower_bound(A_modes, max_product_length, max_products)
    worst = [modes[s] for s in seq]
    certificate = None
    solver_time = 0.0
    if bound >= 1.0:
        stable = False
        if len(worst) == 1:
            reason = f"mode (plant {worst[0][0]}, eta {worst[0][1]}) has spectral radius {bound:.6g} >= 1"
        else:
            reason = (
                f"repeating the sequence of {len(worst)} intervals in worst_sequence gives "
                f"rho^(1/{len(worst)}) = {bound:.6g} >= 1"
            )
    else:
        try:
            X, t, info = theorem1_lmi(A, solver=solver)
            solver_time = info.solve_time
        except SolverFailed as err:
            X, t = None, -np.inf
            reason_fail = str(err)
        else:
            reason_fail = ""
        if t > 0:
            cert = recheck(lift(X, A), A, "theorem1_lmi", X=X)
            if cert.verified:
                certificate = cert
        if certificate is not None:
            stable = True
            reason = f"Theorem 1 certificate re-checked in float64 (relative margin {certificate.margin:.3g})"
        else:
            stable = None
            reason = (
                "no common quadratic certificate and no destabilizing product up to length "
                f"{checked} (lower bound {bound:.6g} < 1)" + (f"; {reason_fail}" if reason_fail else "")
            )
    return AnalysisReport(
        stable=stable,
        spectral_radii=radii,
        certificate=certificate,
        jsr_lower_bound=bound,
        worst_sequence=worst,
        product_length_checked=checked,
        reason=reason,
        timings={"total": time.perf_counter() - start, "solver": solver_time},
    )
