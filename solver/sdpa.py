"""The design SDP in SDPA sparse format (``.dat-s``), for re-solving it elsewhere (docs/design.md, "Deployment").

SDPA's primal problem is::

    minimize  c^T x   subject to   sum_i x_i F_i - F_0 >= 0   (block diagonal)

``design`` solves ``max t`` subject to ``trace W = n`` and the block LMIs ``>= t I``
(:mod:`solver.methods.lmi`, :mod:`solver.methods.switched`).  SDPA has no equality
constraints, so the last diagonal entry of ``W`` (of ``Z`` for ``switched``) is
eliminated with the normalization, and ``c = -e_t``: the SDPA optimum is ``-t*`` where
``t* = res.history[-1].objective``.  The data are exactly those ``design`` hands its
solver: the congruent form (mode s multiplied by ``c_s = lambda^(-eta_s)`` for a decay
rate) and, when ``scaling="auto"`` balances the family, the balanced coordinates.
"""

from __future__ import annotations

import io
import itertools

import numpy as np

from .design import METHODS, RATE_METHODS
from .errors import InvalidInput
from .methods import switched as switched_method
from .methods.common import congruent_scale
from .network import MAX_MODES, ModeSet
from .plant import PlantFamily
from .scaling import balance

#: Options of :func:`solver.design` that change how the SDP is solved, not which SDP.
_SOLVE_ONLY = ("solver", "margin", "max_iter", "time_limit", "callback", "rate_tol", "ccl_start")


def _variables(method: str, n: int, m: int, S: int, J: int):
    """Names of the SDPA variables and, per variable, a function adding its unit value to the blocks."""
    names = ["t"]
    # W (lmi, symmetric) or Z (switched, general): the last diagonal entry is n minus the others.
    mat = "W" if method == "lmi" else "Z"
    pairs = [(a, b) for a in range(n) for b in range(a if method == "lmi" else 0, n) if (a, b) != (n - 1, n - 1)]
    units = [("t", None)]
    for a, b in pairs:
        names.append(f"{mat}[{a},{b}]")
        units.append((mat, (a, b)))
    if method == "switched":
        for s in range(S):
            for a in range(n):
                for b in range(a, n):
                    names.append(f"S_{s}[{a},{b}]")
                    units.append(("S", (s, a, b)))
    for j in range(J):
        for a in range(m):
            for b in range(n):
                names.append(f"Y_{j}[{a},{b}]")
                units.append(("Y", (j, a, b)))
    return names, units


def _blocks(method, free, coef, active, t, X, Sm, Y):
    """The LMI blocks (B, 2n, 2n) at the given variable values (linear in them)."""
    S, n = free.shape[0], free.shape[1]
    AX = free @ X + np.einsum("sjab,sj,jbc->sac", coef, active.astype(float), Y)
    eye = t * np.eye(2 * n)
    if method == "lmi":
        out = np.empty((S, 2 * n, 2 * n))
        out[:, :n, :n] = X
        out[:, n:, n:] = X
        out[:, n:, :n] = AX
        out[:, :n, n:] = np.swapaxes(AX, 1, 2)
        return out - eye
    out = np.empty((S, S, 2 * n, 2 * n))
    out[:, :, :n, :n] = (X + X.T)[None, None] - Sm[:, None]
    out[:, :, n:, n:] = Sm[None, :]
    out[:, :, n:, :n] = AX[:, None]
    out[:, :, :n, n:] = np.swapaxes(AX, 1, 2)[:, None]
    return (out - eye).reshape(S * S, 2 * n, 2 * n)


def export_sdpa(family: PlantFamily, n_drop: int, method: str = "lmi", *, decay_rate: float | None = None,
                plant_switching: str = "per_interval", scheme: str = "predictive", max_modes: int = MAX_MODES,
                scaling: str = "auto", **options) -> str:
    """The SDP that :func:`solver.design` solves, as SDPA sparse text (``.dat-s``).

    Parameters
    ----------
    family : PlantFamily
    n_drop : int
    method : {"lmi", "switched"}
        ``"ccl"`` solves a sequence of SDPs whose data depend on the previous iterate
        (cone complementarity linearization): no single SDP to export; InvalidInput.
    decay_rate : float in (0, 1], optional
        As in :func:`solver.design`; ``"max"`` (a bisection over many SDPs) is refused:
        export at one rate, e.g. ``res.decay_rate``.
    plant_switching, scheme, max_modes, scaling
        As in :func:`solver.design`: they decide the SDP.
    **options
        The other options of :func:`solver.design` (``solver``, ``margin``,
        ``time_limit``, ...) are accepted and ignored: they change how the SDP is
        solved, not which.

    Returns
    -------
    str
        SDPA sparse format; comment lines (starting with ``*``) say what the variables
        are, which coordinates, and that the optimum is ``-res.history[-1].objective``.

    Notes
    -----
    Variables: ``t``, then the entries of ``W`` (upper triangle; ``lmi``) or ``Z`` (all;
    ``switched``) except the last diagonal one, the upper triangles of ``S_s``
    (``switched``), then every ``Y_j`` row by row.  Gains in the solved coordinates
    are ``Theta_j = Y_j W^{-1}`` (``Z^{-1}``), ``K_q = sum_j M[q, j] Theta_j`` with the
    scheme's map M, and in the user's coordinates ``K_q = U K~_q T^{-1}`` (the header gives
    the diagonals of T and U).
    """
    if not isinstance(family, PlantFamily):
        raise InvalidInput("family must be a PlantFamily", ("family",))
    if method not in METHODS:
        raise InvalidInput(f"method must be one of {sorted(METHODS)}, got {method!r}", ("method",))
    if method == "ccl":
        raise InvalidInput("ccl solves a sequence of SDPs, each built from the previous iterate (cone "
                           "complementarity linearization): there is no single SDP to export; export "
                           "method 'lmi' or 'switched'", ("method",))
    unknown = sorted(set(options) - set(_SOLVE_ONLY))
    if unknown:
        raise InvalidInput(f"export_sdpa does not know the option {unknown[0]!r}", (unknown[0],))
    if decay_rate is not None:
        if decay_rate == "max":
            raise InvalidInput("decay_rate='max' is a bisection over many SDPs: export one rate "
                               "(e.g. res.decay_rate)", ("decay_rate",))
        if isinstance(decay_rate, bool) or not isinstance(decay_rate, (int, float)) or not 0 < decay_rate <= 1:
            raise InvalidInput("decay_rate must be a number in (0, 1]", ("decay_rate",))
    if method not in RATE_METHODS and decay_rate is not None:  # pragma: no cover - ccl refused above
        raise InvalidInput(f"decay_rate is available with methods {RATE_METHODS}", ("decay_rate",))
    if scaling not in ("auto", "none"):
        raise InvalidInput("scaling must be 'auto' or 'none'", ("scaling",))
    scale = balance(family) if scaling == "auto" else None
    solved = family if scale is None or scale.is_identity else scale.family(family)
    modes = ModeSet.from_family(solved, n_drop, plant_switching=plant_switching, scheme=scheme, max_modes=max_modes)
    if method == "switched" and modes.n_modes > switched_method.MAX_MODES:
        raise InvalidInput(f"the switched design has {modes.n_modes}^2 pairwise LMIs; at most "
                           f"{switched_method.MAX_MODES} modes are allowed", ("n_drop",))
    c = congruent_scale(modes, decay_rate)
    coef, active = modes.scheme_coef()
    free = modes.free * c[:, None, None]
    coef = coef * c[:, None, None, None]
    S, n, m, J = modes.n_modes, modes.n_states, modes.n_inputs, modes.n_free_gains
    names, units = _variables(method, n, m, S, J)

    def blocks_at(t=0.0, X=None, Sm=None, Y=None):
        X = np.zeros((n, n)) if X is None else X
        Sm = np.zeros((S, n, n)) if Sm is None else Sm
        Y = np.zeros((J, m, n)) if Y is None else Y
        return _blocks(method, free, coef, active, t, X, Sm, Y)

    last = np.zeros((n, n))
    last[n - 1, n - 1] = float(n)
    constant = blocks_at(X=last)  # the LMI's value at x = 0: W (Z) = n e_n e_n^T
    def unit_blocks():  # one variable at a time: the blocks of all variables together need S (2n)^2 each
        for kind, where in units:
            if kind == "t":
                yield blocks_at(t=1.0)
            elif kind in ("W", "Z"):
                a, b = where
                E = np.zeros((n, n))
                E[a, b] = 1.0
                if kind == "W":
                    E[b, a] = 1.0
                if a == b:
                    E[n - 1, n - 1] = -1.0  # the eliminated diagonal entry absorbs the trace
                yield blocks_at(X=E)
            elif kind == "S":
                s, a, b = where
                Sm = np.zeros((S, n, n))
                Sm[s, a, b] = Sm[s, b, a] = 1.0
                yield blocks_at(Sm=Sm)
            else:
                j, a, b = where
                Y = np.zeros((J, m, n))
                Y[j, a, b] = 1.0
                yield blocks_at(Y=Y)

    out = io.StringIO()
    _header(out, method, family, modes, decay_rate, scale, names, n, len(constant))
    out.write(f"{len(names)} = mDIM\n{len(constant)} = nBLOCK\n")
    out.write(" ".join([str(2 * n)] * len(constant)) + " = bLOCKsTRUCT\n")
    out.write(" ".join(["-1.0"] + ["0.0"] * (len(names) - 1)) + "\n")
    upper = np.triu_indices(2 * n)
    for index, F in enumerate(itertools.chain([-constant], unit_blocks())):  # F_0 = -(the constant part)
        vals = F[:, upper[0], upper[1]]
        for blk, k in zip(*np.nonzero(vals)):
            out.write(f"{index} {blk + 1} {upper[0][k] + 1} {upper[1][k] + 1} {float(vals[blk, k])!r}\n")
    return out.getvalue()


def _header(out, method, family, modes, decay_rate, scale, names, n, blocks):
    S = modes.n_modes
    lines = [
        f"ncs-design: the {method} design SDP of solver.design (docs/design.md), SDPA sparse format.",
        f"family: {family.name or 'unnamed'}; n = {n} states, m = {modes.n_inputs} inputs, "
        f"{modes.n_plants} plant modes, n_drop = {modes.n_drop}, {S} interval modes ({modes.plant_switching}), "
        f"scheme {modes.scheme}.",
        "SDPA primal: minimize c'x subject to sum_i x_i F_i - F_0 >= 0; here c = -e_1, x_1 = t.",
        "design solves max t s.t. trace W = n and the block LMIs >= t I: the optimum of this file is -t*,",
        "t* = res.history[-1].objective (up to the solvers' tolerances).",
    ]
    if method == "lmi":
        lines.append("blocks: one per interval mode s, [[W, (A_s W)']; [A_s W, W]] - t I,"
                     " A_s W = c_s (free_s W + sum_j coef_sj Y_j).")
        lines.append(f"W[{n - 1},{n - 1}] (0-based) is eliminated: n minus the other diagonal entries.")
    else:
        lines.append("blocks: one per pair of modes (s, u) at s*S + u, "
                     "[[Z + Z' - S_s, (A_s Z)']; [A_s Z, S_u]] - t I, A_s Z = c_s (free_s Z + sum_j coef_sj Y_j).")
        lines.append(f"trace(Z + Z') = 2n: Z[{n - 1},{n - 1}] (0-based) is eliminated.")
    lines.append("c_s = 1 (plain stability)" if decay_rate is None else
                 f"c_s = lambda^(-eta_s), decay rate lambda = {float(decay_rate)!r}")
    lines.append("gains: Theta_j = Y_j W^-1 (Z^-1), K_q = sum_j M[q,j] Theta_j (scheme map M).")
    if scale is not None and not scale.is_identity:
        lines.append("balanced coordinates x = T x~, u = U u~: K_q = U K~_q T^-1 with diagonals")
        lines.append(f"  T = {scale.state.tolist()}")
        lines.append(f"  U = {scale.input.tolist()}")
    else:
        lines.append("coordinates: the family's own (no balancing).")
    lines.append(f"variables ({len(names)}, 1-based in order):")
    lines += ["  " + " ".join(names[i:i + 8]) for i in range(0, len(names), 8)]
    for line in lines:
        out.write("* " + line.replace("\n", " ") + "\n")
