"""Exact arithmetic on float64 data: proofs that a spectral radius is at least a bound.

Every float64 number is a dyadic rational ``m / 2^e``, so products and sums of
the user's matrices can be computed exactly with Python integers.  A matrix
is held as ``(M, s)``: an object array of ints and an exponent, value ``M / 2^s``.

``rho(A) >= r`` is decided exactly (docs/design.md, "Rigorous instability"):
the characteristic polynomial of the integer matrix is computed by
Faddeev-LeVerrier (all divisions exact for integer matrices), rescaled to
``p(r z)``, and the Schur-Cohn-Jury recursion decides whether all its roots lie
in the open unit disk.  If not, some eigenvalue has ``|lambda| >= r``: a proof,
without eigenvalue approximations.
"""

from __future__ import annotations

from fractions import Fraction
from math import gcd

import numpy as np

from .memo import BoundedCache


def exact(a) -> tuple[np.ndarray, int]:
    """``(M, s)`` with ``a == M / 2^s`` exactly, for a float64 array (any shape)."""
    a = np.asarray(a, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise ValueError("exact arithmetic needs finite data")
    ratios = [float(x).as_integer_ratio() for x in a.ravel()]
    s = max((d.bit_length() - 1 for _, d in ratios), default=0)
    M = np.array([num << (s - (d.bit_length() - 1)) for num, d in ratios], dtype=object).reshape(a.shape)
    return M, s


def _align(a: tuple, b: tuple) -> tuple:
    (A, s), (B, t) = a, b
    if s < t:
        A, s = A * (1 << (t - s)), t
    elif t < s:
        B = B * (1 << (s - t))
    return A, B, s


def add(a: tuple, b: tuple) -> tuple:
    A, B, s = _align(a, b)
    return A + B, s


def matmul(a: tuple, b: tuple) -> tuple:
    return np.dot(a[0], b[0]), a[1] + b[1]


def transpose(a: tuple) -> tuple:
    """``a'`` of an ``(M, s)`` pair."""
    return a[0].T.copy(), a[1]


def bits(M) -> int:
    """The largest bit length of the integers ``M`` (an array of any shape)."""
    return max((abs(int(v)).bit_length() for v in np.asarray(M, dtype=object).ravel()), default=0)


def identity(n: int) -> tuple:
    M = np.zeros((n, n), dtype=object)
    for i in range(n):
        M[i, i] = 1
    return M * 1, 0


def closed_loop(F: np.ndarray, G: np.ndarray, K: np.ndarray, seq) -> tuple:
    """Exact interval map ``A = F^eta + sum_t F^t G K_{eta-t}`` for plant sequence ``seq`` (eta = len(seq)).

    Sample k of the interval applies ``x <- F_{l_k} x + G_{l_k} K_{k+1} x(i_m)``.
    """
    n = F.shape[1]
    Fe = [exact(F[l]) for l in range(F.shape[0])]
    Ge = [exact(G[l]) for l in range(G.shape[0])]
    Ke = [exact(K[q]) for q in range(K.shape[0])]
    x = identity(n)  # the map x(i_m) -> x(i_m + k)
    for k, l in enumerate(seq):
        x = add(matmul(Fe[l], x), matmul(Ge[l], Ke[k]))
    return x


def charpoly(M: np.ndarray) -> list[int]:
    """Integer coefficients ``[c_0, ..., c_n]`` (``c_n = 1``) of ``det(z I - M)`` for an integer matrix."""
    n = M.shape[0]
    c = [0] * (n + 1)
    c[n] = 1
    eye = identity(n)[0]
    Mk = eye * 1  # M_1 = I
    for k in range(1, n + 1):
        AM = np.dot(M, Mk)
        tr = sum(AM[i, i] for i in range(n))
        assert tr % k == 0
        c[n - k] = -tr // k
        Mk = AM + c[n - k] * eye
    return [int(v) for v in c]


def schur_stable(a: list[int]) -> bool:
    """Whether every root of ``sum_k a[k] z^k`` (integers, a[-1] != 0) lies in the open unit disk.

    Schur-Cohn-Jury: ``p`` is Schur stable iff ``|a_0| < |a_n|`` and
    ``(a_n p(z) - a_0 z^n p(1/z)) / z`` is Schur stable; exact over the integers.
    """
    a = list(a)
    while len(a) > 1:
        n = len(a) - 1
        if abs(a[0]) >= abs(a[n]):
            return False
        b = [a[n] * a[k] - a[0] * a[n - k] for k in range(1, n + 1)]
        g = 0
        for v in b:
            g = gcd(g, v)
        a = [v // g for v in b] if g > 1 else b
    return True


def radius_at_least(M: tuple, r: Fraction) -> bool:
    """True iff ``rho(M / 2^s) >= r`` is proven (exactly decided: False means ``rho < r``).

    Parameters
    ----------
    M : tuple (object ndarray of int, int)
        The exact matrix ``M / 2^s``.
    r : Fraction
        Radius > 0.
    """
    Mi, s = M
    c = charpoly(Mi)
    n = len(c) - 1
    r = Fraction(r)
    # roots of p_M in the disk of radius r  <=>  p_i(2^s r z) Schur stable; 2^s r = num / den
    num, den = r.numerator << s, r.denominator
    coeffs = [c[k] * num**k * den ** (n - k) for k in range(n + 1)]
    return not schur_stable(coeffs)


def product(mats: list[tuple]) -> tuple:
    """Exact ``mats[-1] @ ... @ mats[0]`` (the first applied first)."""
    out = mats[0]
    for m in mats[1:]:
        out = matmul(m, out)
    return out


def proven_radius_lower_bound(M: tuple, estimate: float, steps: int = 40) -> float:
    """The largest ``r`` (a float) with ``rho(M) >= r`` proven, searched near ``estimate``; 0.0 if none.

    Tries ``estimate (1 - 1e-9)`` first, then bisects on ``[0, estimate]``.
    """
    if not np.isfinite(estimate) or estimate <= 0:
        return 0.0
    first = Fraction(estimate * (1 - 1e-9))
    if radius_at_least(M, first):
        return float(first) * (1 - 2.0**-52)  # float(first) may round up by half an ulp
    lo, hi = Fraction(0), first
    for _ in range(steps):
        mid = (lo + hi) / 2
        mid = Fraction(float(mid))  # keep the numbers short
        if radius_at_least(M, mid):
            lo = mid
        else:
            hi = mid
    return float(lo) * (1 - 2.0**-52)


# ------------------------------------------------------------------ rational matrices
def proven_rate(mats: list[tuple], estimate: float) -> tuple[float | None, bool]:
    """What exact arithmetic proves about the product ``M = mats[-1] ... mats[0]`` of ``k`` exact matrices.

    Returns ``(a proven lower bound of rho(M)^(1/k), or None when no positive one could be proven; whether
    rho(M) >= 1 is proven)``; ``estimate`` is the float64 estimate of ``rho(M)^(1/k)`` the bound starts from.
    """
    M = product(mats)
    k = len(mats)
    unstable = radius_at_least(M, Fraction(1))
    lb = proven_radius_lower_bound(M, estimate**k, steps=30)
    if lb <= 0:
        return None, unstable
    bound = lb ** (1.0 / k) * (1 - 8 * 2.0**-53)
    return (max(bound, 1.0) if unstable else bound), unstable


def fractions(a) -> list[list[Fraction]]:
    """A float64 matrix as exact Fractions."""
    return [[Fraction(float(x)) for x in row] for row in np.asarray(a, dtype=np.float64)]


def floats(M) -> np.ndarray:
    """A rational matrix (lists of Fractions) rounded entry by entry to float64 (the inverse of :func:`fractions`
    on float64 input)."""
    return np.array([[float(v) for v in row] for row in M], dtype=np.float64)


def charpoly_rational(M: list[list[Fraction]]) -> list[Fraction]:
    """Coefficients ``[c_0, ..., c_n]`` of ``det(z I - M)`` for a rational matrix (Faddeev-LeVerrier)."""
    n = len(M)
    c = [Fraction(0)] * (n + 1)
    c[n] = Fraction(1)
    Mk = [[Fraction(int(i == j)) for j in range(n)] for i in range(n)]
    for k in range(1, n + 1):
        AM = [[sum(M[i][l] * Mk[l][j] for l in range(n)) for j in range(n)] for i in range(n)]
        c[n - k] = -sum(AM[i][i] for i in range(n)) / k
        Mk = [[AM[i][j] + (c[n - k] if i == j else 0) for j in range(n)] for i in range(n)]
    return c


def rational_radius_at_least(coeffs: list[Fraction], r: Fraction) -> bool:
    """True iff the polynomial ``sum_k coeffs[k] z^k`` (leading coefficient nonzero) has a root with ``|z| >= r``."""
    n = len(coeffs) - 1
    if n == 0:
        return False
    scaled = [Fraction(a) * Fraction(r) ** k for k, a in enumerate(coeffs)]
    den = 1
    for v in scaled:
        den = den * v.denominator // gcd(den, v.denominator)
    return not schur_stable([int(v * den) for v in scaled])


def uncontrollable_part(F, G) -> list[list[Fraction]]:
    """The map induced by F on ``R^n / (controllable subspace of (F, G))``, exactly (may be 0 x 0).

    The controllable subspace ``V = span[G, F G, ..., F^(n-1) G]`` is F-invariant; with a basis
    ``T = [V, E]`` (E unit vectors completing it) ``T^-1 F T`` is block upper triangular and its
    lower-right block is the uncontrollable part: its eigenvalues are exactly the eigenvalues
    of F that no input reaches.
    """
    Fq = fractions(F)
    Gq = fractions(G)
    n = len(Fq)
    basis: list[list[Fraction]] = []  # reduced rows (echelon) spanning V, stored as vectors
    pivots: list[int] = []

    def reduce(v):
        v = v[:]
        for b, p in zip(basis, pivots):
            if v[p] != 0:
                f = v[p] / b[p]
                v = [x - f * y for x, y in zip(v, b)]
        return v

    vectors = [[Gq[i][j] for i in range(n)] for j in range(len(Gq[0]))]
    queue = list(vectors)
    V = []
    while queue and len(V) < n:
        v = queue.pop(0)
        r = reduce(v)
        p = next((i for i, x in enumerate(r) if x != 0), None)
        if p is None:
            continue
        basis.append(r)
        pivots.append(p)
        V.append(v)
        queue.append([sum(Fq[i][k] * v[k] for k in range(n)) for i in range(n)])  # F v
    k = len(V)
    if k == n:
        return []
    cols = V + [[Fraction(int(i == j)) for i in range(n)] for j in range(n) if j not in pivots]
    T = [[cols[j][i] for j in range(n)] for i in range(n)]
    # solve T X = F T exactly (Gauss-Jordan on [T | F T])
    FT = [[sum(Fq[i][l] * T[l][j] for l in range(n)) for j in range(n)] for i in range(n)]
    aug = gauss_jordan([T[i][:] + FT[i][:] for i in range(n)])  # T is invertible (a basis)
    X = [row[n:] for row in aug]
    return [row[k:] for row in X[k:]]


def gauss_jordan(aug: list) -> list | None:
    """Reduce ``[H | B]`` (k rows of Fractions) to ``[I | H^-1 B]`` exactly; None when H is singular."""
    k = len(aug)
    for c in range(k):
        piv = next((r for r in range(c, k) if aug[r][c] != 0), None)
        if piv is None:
            return None
        aug[c], aug[piv] = aug[piv], aug[c]
        pv = aug[c][c]
        aug[c] = [x / pv for x in aug[c]]
        for r in range(k):
            if r != c and aug[r][c] != 0:
                f = aug[r][c]
                aug[r] = [x - f * y for x, y in zip(aug[r], aug[c])]
    return aug


def solve_integer(M, B) -> tuple[list[list[int]], int] | None:
    """Solve ``M X = B`` exactly for an integer matrix ``M`` (k x k) and integer right-hand sides ``B`` (k x p):
    ``(X_num, d)`` with ``M X_num = d B``, ``X = X_num / d`` (``d = +-det M``, nonzero; integers), or None when M is
    singular.

    Fraction-free (Bareiss) elimination: every division is exact, so the integers stay of the size of the minors
    (Hadamard) instead of growing like the products of Gauss-Jordan's Fractions; the back substitution divides
    ``d b - sum_{j>i} a_ij X_j`` by the pivot row's ``a_ii``, exact because ``d x_i`` is an integer (Cramer).
    """
    k = len(M)
    p = len(B[0]) if k else 0
    a = [[int(v) for v in M[i]] + [int(v) for v in B[i]] for i in range(k)]
    prev = 1
    for c in range(k):
        piv = next((r for r in range(c, k) if a[r][c] != 0), None)
        if piv is None:
            return None
        a[c], a[piv] = a[piv], a[c]
        pc, rowc = a[c][c], a[c]
        for r in range(c + 1, k):
            row, arc = a[r], a[r][c]
            a[r] = [0] * (c + 1) + [(pc * row[j] - arc * rowc[j]) // prev for j in range(c + 1, k + p)]
        prev = pc
    d = a[k - 1][k - 1] if k else 1
    X = [[0] * p for _ in range(k)]
    for i in range(k - 1, -1, -1):
        row = a[i]
        for col in range(p):
            rest = d * row[k + col] - sum(row[j] * X[j][col] for j in range(i + 1, k))
            q, r = divmod(rest, row[i])
            if r:  # cannot happen (Cramer): a wrong answer would be worse than none
                raise ArithmeticError("fraction-free back substitution left a remainder")
            X[i][col] = q
    return X, d


def dyadic(M) -> tuple[list[list[int]], int]:
    """``(N, s)`` with ``M == N / 2^s`` exactly, for a matrix of dyadic Fractions (lists of rows, or an
    ``exact``-style pair)."""
    if isinstance(M, tuple):
        N, s = M
        return [[int(v) for v in row] for row in N], s
    s = max((Fraction(v).denominator.bit_length() - 1 for row in M for v in row), default=0)
    out = []
    for row in M:
        r = []
        for v in row:
            v = Fraction(v)
            den = v.denominator
            if den & (den - 1):
                raise ValueError("not a dyadic rational")
            r.append(v.numerator << (s - (den.bit_length() - 1)))
        out.append(r)
    return out, s


def positive_definite_shifted(M, shift: float) -> bool:
    """Exactly decide whether ``M + shift I`` is positive definite, for a symmetric float64 matrix M.

    Sylvester's criterion on the integer matrix ``2^s (M + shift I)`` (all float64 numbers are
    dyadic): fraction-free (Bareiss) elimination, every leading principal minor must be > 0.
    """
    A = np.asarray(M, dtype=np.float64)
    n = A.shape[0]
    A = A + 0.0  # copy
    Mi, s = exact(A)
    sh, t = exact(np.array([shift]))
    if t > s:
        Mi, s = Mi * (1 << (t - s)), t
    shv = int(sh[0]) << (s - t)
    return positive_definite_integer([[int(Mi[i, j]) + (shv if i == j else 0) for j in range(n)] for i in range(n)])


def positive_definite_integer(B) -> bool:
    """Exactly decide whether the symmetric integer matrix ``B`` (lists or an object array) is positive definite:
    Sylvester's criterion by fraction-free (Bareiss) elimination, every leading principal minor must be > 0."""
    n = len(B)
    B = [[int(B[i][j]) for j in range(n)] for i in range(n)]
    prev = 1
    for k in range(n):
        if B[k][k] <= 0:
            return False
        for i in range(k + 1, n):
            for j in range(k + 1, n):
                B[i][j] = (B[i][j] * B[k][k] - B[i][k] * B[k][j]) // prev
        prev = B[k][k]
    return True


def stein_floor(Phi: tuple, Q: tuple, O: np.ndarray, Phif: np.ndarray) -> tuple | None:
    """A rational ``O_low <= O_true = sum_i Phi'^i Q Phi^i`` (exact ``(N, s)``), or None.

    ``Phi``, ``Q`` exact ``(N, s)`` pairs (n x n, Q symmetric); ``O`` and ``Phif`` float64 approximations of O_true
    and Phi (any will do: the checks are exact).  Checked exactly: ``L > 0`` and ``L - Phi' L Phi - I/2 > 0`` (Phi
    stable, L from Phif) and ``Q + Phi' O_low Phi - O_low > 0`` for ``O_low = (1 - eps) O`` or ``O - eps |O| L``
    (eps from 1e-14 up); iterating the last, ``O_low <= sum_{i<J} Phi'^i Q Phi^i + Phi'^J O_low Phi^J``, whose last
    term vanishes as J grows (docs/design.md §8.4, "Exact witness (cost)").  O_low need not be semidefinite."""
    from .periodic import stein_doubling

    n = Phif.shape[0]
    if not any(Q[0].ravel()):  # O_true = 0 exactly, whatever Phi
        return np.zeros((n, n), dtype=object) * 0, 0
    L = stein_doubling(Phif[None], np.eye(n)[None])[0][0]
    L = 0.5 * (L + L.T)
    if not np.all(np.isfinite(L)) or not np.all(np.isfinite(O)):
        return None

    def negative(X):
        return -X[0], X[1]

    def definite(X) -> bool:
        return positive_definite_integer([[int(X[0][i, j]) for j in range(n)] for i in range(n)])

    Le, half = exact(L), exact(0.5 * np.eye(n))
    decrease = add(add(Le, negative(matmul(matmul(transpose(Phi), Le), Phi))), negative(half))
    if not (definite(Le) and definite(decrease)):
        return None
    scale, Os = float(np.linalg.norm(O, 2)), 0.5 * (O + O.T)
    for eps in (1e-14, 1e-12, 1e-10, 1e-8):
        # O shrunk first (it adds eps (O - Phi' O Phi) ~ eps Q to the residual and costs eps of the value), then
        # less eps |O| L (any Q, singular too; it costs eps |O| <L, M>, up to 1e-6 relative on a badly scaled slowly
        # contracting loop)
        for Ol in (exact((1.0 - eps) * Os), exact(Os - eps * scale * L)):
            if definite(add(add(Q, matmul(matmul(transpose(Phi), Ol), Phi)), negative(Ol))):
                return Ol
    return None


def lyapunov_decrease(X: np.ndarray, F: np.ndarray, G: np.ndarray, K: np.ndarray, plants, shift: float = 0.0) -> bool:
    """Exactly decide ``X > 0`` and ``X - A_s' X A_s > shift I`` for every mode, on the float64 numbers.

    ``A_s`` is the interval map of mode s (plant sequence ``plants[s]``) computed exactly from the float64 ``F``,
    ``G`` and gains ``K`` (:func:`closed_loop`), and ``X`` (n x n, symmetrized exactly) is taken as exact: the
    stability re-check where float64 cannot decide (a relative margin of 1e-11 where P spans 1e11,
    docs/design.md §8.5).  Integer matrices with a power-of-two denominator, :func:`positive_definite_integer`.
    """
    X = np.asarray(X, dtype=np.float64)
    if not np.all(np.isfinite(X)) or not np.all(np.isfinite(K)):
        return False
    Xi, t = exact(X)
    Xs = Xi + Xi.T  # 2 X, exactly symmetric: value Xs / 2^(t+1)
    if not positive_definite_integer(Xs):
        return False
    p, q = float(shift).as_integer_ratio()  # shift = p / q exactly, q a power of two
    for seq in plants:
        Ai, s = closed_loop(F, G, K, seq)
        AXA = np.dot(np.dot(Ai.T, Xs), Ai)  # value AXA / 2^(2s+t+1)
        D = (Xs * (1 << (2 * s)) - AXA) * q  # value D / (q 2^(2s+t+1)); minus shift I: p 2^(2s+t+1) off the diagonal
        if p:
            D = D - p * (1 << (2 * s + t + 1)) * np.eye(D.shape[0], dtype=int).astype(object)
        if not positive_definite_integer(D):
            return False
    return True


def rational_up(q: Fraction) -> float:
    """The least float64 number ``>= q`` (``float`` rounds to nearest: one step up when it fell below)."""
    f = float(q)
    return f if Fraction(f) >= q else float(np.nextafter(f, np.inf))


def rational_down(q: Fraction) -> float:
    """The largest float64 number ``<= q``."""
    f = float(q)
    return f if Fraction(f) <= q else float(np.nextafter(f, -np.inf))


#: Largest bit length of a numerator or denominator :func:`lyapunov_exact` returns: its decimal string (the JSON
#: form ``"p/q"``, ``str`` of a Fraction) stays within Python's default limit of 4300 digits (14284 bits), past which
#: ``str`` raises ValueError.  Float64 data of a wide exponent range reach it (subnormal entries in F or K: 4e4 bits
#: at n = 8, and 100 s of elimination); typical loops need 500-6000 bits (docs/design.md §8.5).
EXACT_MAX_BITS = 14000


#: The last results of :func:`lyapunov_exact`, by the bytes of its float64 arguments (the Riccati refinement's last
#: exact step and the bracket's exact certificate solve the same loop: one elimination, up to 2 s at n = 8).
_LYAPUNOV_CACHE = BoundedCache(8)


def lyapunov_exact(F, G, K, Q, R, S: list | None = None, definite: bool = True) -> list[list[Fraction]] | None:
    """The exact solution P of ``P = A' P A + S`` for the loop ``A = F + G K``, ``S = Q + K' R K``.

    F (n, n), G (n, m), K (m, n), Q (n, n), R (m, m): float64 numbers taken as exact dyadic rationals, so A and S
    are the deployed loop and its stage cost exactly (not their float64 roundings).  The ``n(n+1)/2`` equations
    in the entries of the symmetric P are solved over the integers (fraction-free Bareiss elimination, then
    back substitution in Fractions); P is returned as Fractions only after ``P - A' P A - S == 0`` and
    ``P > 0`` are verified exactly (for ``S >= 0``: P is then the exact cost matrix of the loop, and a
    certificate of ``x' P x >= x' S x + (A x)' P (A x)``, docs/design.md §8.5).  None when the system is
    singular (A has eigenvalues ``lambda_i lambda_j = 1``), P is not positive definite (A not stable), or P's
    numbers exceed :data:`EXACT_MAX_BITS` (then also None before the elimination when Hadamard's bound on the
    Cramer determinants exceeds four times that: only the time is saved, the result's own size decides).
    O(n^6) big-integer operations: small n only (n <= 8: 36 unknowns).  ``S`` (n x n Fractions, symmetric): the
    stage in place of ``Q + K' R K`` (Q and R then unused; the game's indefinite stages, :func:`game_gain_exact`);
    ``definite=False``: P is returned without the test ``P > 0`` (a Newton iterate, not a certificate).
    """
    if S is not None:  # (a given rational stage: not kept)
        return _lyapunov_exact(F, G, K, Q, R, S, definite)
    arrays = [np.ascontiguousarray(M, dtype=np.float64) for M in (F, G, K, Q, R)]
    key = (definite,) + tuple((M.shape, M.tobytes()) for M in arrays)
    P = _LYAPUNOV_CACHE.get_or_compute(key, lambda: _lyapunov_exact(*arrays, None, definite))
    return None if P is None else [row[:] for row in P]


def _lyapunov_exact(F, G, K, Q, R, S, definite) -> list[list[Fraction]] | None:
    F, G, K = (np.asarray(M, dtype=np.float64) for M in (F, G, K))
    n = F.shape[0]
    Mi, s = closed_loop(F[None], G[None], K[None], (0,))  # A = Mi / 2^s exactly
    if S is None:
        Kq, Qq, Rq = fractions(K), fractions(Q), fractions(R)
        m = len(Rq)
        Sq = [[(Qq[i][j] + Qq[j][i]) / 2 + sum(Kq[a][i] * (Rq[a][b] + Rq[b][a]) / 2 * Kq[b][j]
                                               for a in range(m) for b in range(m))
               for j in range(n)] for i in range(n)]
    else:
        Sq = [[(Fraction(S[i][j]) + Fraction(S[j][i])) / 2 for j in range(n)] for i in range(n)]
    den = 1
    for row in Sq:
        for v in row:
            den = den * v.denominator // gcd(den, v.denominator)
    M = [[int(Mi[i, j]) for j in range(n)] for i in range(n)]
    four = 1 << (2 * s)
    pairs = [(i, j) for i in range(n) for j in range(i, n)]
    index = {p: k for k, p in enumerate(pairs)}
    N = len(pairs)
    # equation (i, j): 4^s P_ij - sum_kl M_ki M_lj P_kl = 4^s S_ij, unknowns P_kl (k <= l), times den: integers
    rows = []
    for (i, j) in pairs:
        row = [0] * (N + 1)
        row[index[(i, j)]] += four
        for k in range(n):
            for l in range(n):
                c = M[k][i] * M[l][j]
                if c:
                    row[index[(k, l) if k <= l else (l, k)]] -= c
        row[N] = four * int(Sq[i][j] * den)
        rows.append(row)
    # Hadamard: every minor of the augmented system has at most N (width + log2(N + 1) / 2) bits
    width = max(abs(v).bit_length() for row in rows for v in row)
    if N * (width + (N + 1).bit_length()) + den.bit_length() > 4 * EXACT_MAX_BITS:
        return None
    # Bareiss forward elimination (row swaps on zero pivots), every division exact
    prev = 1
    for c in range(N):
        piv = next((r for r in range(c, N) if rows[r][c] != 0), None)
        if piv is None:
            return None
        rows[c], rows[piv] = rows[piv], rows[c]
        pc = rows[c]
        for r in range(c + 1, N):
            rr = rows[r]
            f = rr[c]
            rows[r] = [0] * (c + 1) + [(rr[k] * pc[c] - f * pc[k]) // prev for k in range(c + 1, N + 1)]
        prev = pc[c]
    x = [Fraction(0)] * N
    for c in range(N - 1, -1, -1):
        x[c] = (rows[c][N] - sum(rows[c][k] * x[k] for k in range(c + 1, N))) / Fraction(rows[c][c])
    P = [[x[index[(i, j) if i <= j else (j, i)]] / den for j in range(n)] for i in range(n)]
    # the verification (independent of the elimination): the equation exactly, then P > 0 exactly
    Aq = [[Fraction(M[i][j], 1 << s) for j in range(n)] for i in range(n)]
    AP = [[sum(Aq[k][i] * P[k][j] for k in range(n)) for j in range(n)] for i in range(n)]  # A' P
    for i in range(n):
        for j in range(n):
            if P[i][j] - sum(AP[i][k] * Aq[k][j] for k in range(n)) - Sq[i][j] != 0:
                return None
    pden = 1
    for row in P:
        for v in row:
            pden = pden * v.denominator // gcd(pden, v.denominator)
    if definite and not positive_definite_integer([[int(v * pden) for v in row] for row in P]):
        return None
    if max(max(v.numerator.bit_length(), v.denominator.bit_length()) for row in P for v in row) > EXACT_MAX_BITS:
        return None  # (its "p/q" strings would exceed Python's int-to-str limit)
    return P


def riccati_gain_exact(F, G, R, P: list[list[Fraction]]) -> np.ndarray | None:
    """Hewer's gain update ``K = -(R + G' P G)^{-1} G' P F`` in exact arithmetic, rounded once to float64.

    F (n, n), G (n, m), R (m, m) float64 taken as exact; P (n x n Fractions, e.g. :func:`lyapunov_exact`).  Where
    P spans 1e13 the float64 products ``G' P F`` cancel to a few digits; here only the final rounding is inexact
    (docs/design.md §8.5).  Returns (m, n), or None when ``R + G' P G`` is singular.
    """
    Fq, Gq, Rq = fractions(F), fractions(G), fractions(R)
    n, m = len(Fq), len(Rq)
    GP = [[sum(Gq[k][a] * P[k][j] for k in range(n)) for j in range(n)] for a in range(m)]  # G' P
    H = [[Rq[a][b] + sum(GP[a][k] * Gq[k][b] for k in range(n)) for b in range(m)] for a in range(m)]
    rhs = [[-sum(GP[a][k] * Fq[k][j] for k in range(n)) for j in range(n)] for a in range(m)]
    aug = gauss_jordan([H[a][:] + rhs[a][:] for a in range(m)])  # [H | -G'PF] -> [I | K]
    if aug is None:
        return None
    return floats([row[m:] for row in aug])


def game_stage_exact(C, D, L, g, m: int) -> list[list[Fraction]]:
    """The game's stage ``(C + D L)' (C + D L) - g L_w' L_w`` exactly (``L_w = L[m:]``, the disturbance's rows).

    C (q, n), D (q, m + p), L (m + p, n) float64 taken as exact; g a float64 (``gamma^2``) or Fraction.  With
    ``u = L[:m] x``, ``w = L[m:] x`` it is the integrand ``|z|^2 - g |w|^2`` of the H-infinity game (§8.5)."""
    Cq, Dq, Lq, gq = fractions(C), fractions(D), fractions(L), Fraction(g)
    n, q = len(Cq[0]), len(Cq)
    Z = [[Cq[r][j] + sum(Dq[r][a] * Lq[a][j] for a in range(len(Lq))) for j in range(n)] for r in range(q)]
    return [[sum(Z[r][i] * Z[r][j] for r in range(q)) - gq * sum(Lq[a][i] * Lq[a][j] for a in range(m, len(Lq)))
             for j in range(n)] for i in range(n)]


def game_gain_exact(F, G, E, C, Du, Dw, g, X: list[list[Fraction]], K=None):
    """The saddle gains of the H-infinity game at the value matrix X, in exact arithmetic, rounded once.

    ``K`` None: both players, ``L = -(D'D - diag(0, g I) + B'XB)^{-1} (B'XF + D'C)``, ``B = [G E]``,
    ``D = [Du Dw]`` (one Newton step of the game Riccati equation, §8.5).  ``K`` given (m, n): u = K x fixed, the
    disturbance's best reply only, ``L_w = (g I - Dw'Dw - E'XE)^{-1} (E'X (F + G K) + Dw'(C + Du K))`` (a Newton
    step of the loop's bounded-real equation).  Returns ``(L (m + p, n) float64, Hww)``: the full gain ``[K; L_w]``
    and the disturbance block ``Dw'Dw - g I + E'XE`` (p x p Fractions: negative definite at a saddle), or None when
    the block to invert is singular.
    """
    Fq, Gq, Eq, Cq, Duq, Dwq = (fractions(M) for M in (F, G, E, C, Du, Dw))
    gq = Fraction(g)
    n, m, q = len(Fq), len(Gq[0]), len(Cq)
    if K is not None:  # the loop's data: F + G K and C + Du K exactly, u's columns dropped
        Kq = fractions(K)
        Fq = [[Fq[i][j] + sum(Gq[i][a] * Kq[a][j] for a in range(m)) for j in range(n)] for i in range(n)]
        Cq = [[Cq[r][j] + sum(Duq[r][a] * Kq[a][j] for a in range(m)) for j in range(n)] for r in range(q)]
        Bq, Dq, mu = Eq, Dwq, 0
    else:
        Bq = [Gq[i] + Eq[i] for i in range(n)]
        Dq = [Duq[r] + Dwq[r] for r in range(q)]
        mu = m
    k = len(Bq[0])
    BX = [[sum(Bq[i][a] * X[i][j] for i in range(n)) for j in range(n)] for a in range(k)]  # B' X
    H = [[sum(Dq[r][a] * Dq[r][b] for r in range(q)) - (gq if a == b and a >= mu else 0)
          + sum(BX[a][i] * Bq[i][b] for i in range(n)) for b in range(k)] for a in range(k)]
    rhs = [[-(sum(BX[a][i] * Fq[i][j] for i in range(n)) + sum(Dq[r][a] * Cq[r][j] for r in range(q)))
            for j in range(n)] for a in range(k)]
    aug = gauss_jordan([H[a][:] + rhs[a][:] for a in range(k)])
    if aug is None:
        return None
    L = floats([row[k:] for row in aug])
    if K is not None:
        L = np.vstack([np.asarray(K, dtype=np.float64), L])
    return L, [row[mu:] for row in H[mu:]]
