"""The structured interior-point solver (solver/ipm/) against Clarabel and against itself.

No timed assertions: speed is measured by ``python -m bench ipm``.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.ipm_check import MARGIN, check_one, clarabel_t
from solver import PlantFamily, SolverFailed, ipm
from solver.network import ModeSet


def _rand_psd(rng, nb, k):
    A = rng.standard_normal((nb, k, k))
    return A @ np.swapaxes(A, 1, 2) + np.eye(k)


@pytest.mark.parametrize("builder", [ipm.lmi_problem, ipm.switched_problem])
@pytest.mark.parametrize("n_drop", [1, 2])
def test_structured_schur_equals_dense(builder, n_drop):
    """The Kronecker-assembled Schur complement and adjoint equal the brute-force ones."""
    rng = np.random.default_rng(n_drop)
    fam = PlantFamily(F=[rng.standard_normal((3, 3)) for _ in range(2)], G=[rng.standard_normal((3, 2))] * 2)
    modes = ModeSet.from_family(fam, n_drop)
    coef, active = modes.scheme_coef()
    prob = builder(modes.free, coef, active, rho=rng.uniform(0.5, 1.0, modes.n_modes))
    X, G = _rand_psd(rng, prob.nb, prob.k), _rand_psd(rng, prob.nb, prob.k)
    A = prob.dense_operator()
    dense = np.einsum("ibjk,bkl,mblo,boj->im", A, X, A, G)
    assert np.allclose(prob.schur(X, G), dense, rtol=1e-10, atol=1e-10 * np.abs(dense).max())
    y, U = rng.standard_normal(prob.p), rng.standard_normal((prob.nb, prob.k, prob.k))
    assert np.isclose(np.sum(prob.op(y) * U), y @ prob.adj(U))


def test_problems_sharing_a_schur_plan_each_assemble_their_own_schur_complement():
    """Plans are kept by the problem's structure (solver.ipm.schur._PLANS): problems of one structure with other data,
    another gain mask, and of another structure in between, each equal the brute-force Schur complement."""
    rng = np.random.default_rng(11)
    fam = PlantFamily(F=[rng.standard_normal((3, 3)) for _ in range(2)], G=[rng.standard_normal((3, 2))] * 2)
    modes = ModeSet.from_family(fam, 2)
    coef, active = modes.scheme_coef()
    masked = active.copy()
    masked[0] = False
    probs = [ipm.lmi_problem(modes.free, coef, active), ipm.switched_problem(modes.free, coef, active),
             ipm.lmi_problem(2.0 * modes.free, -coef, masked), ipm.lmi_problem(modes.free, coef, active, rho=0.5 + 0 *
                                                                               np.arange(modes.n_modes))]
    for prob in probs + probs[::-1]:
        X, G = _rand_psd(rng, prob.nb, prob.k), _rand_psd(rng, prob.nb, prob.k)
        A = prob.dense_operator()
        dense = np.einsum("ibjk,bkl,mblo,boj->im", A, X, A, G)
        assert np.allclose(prob.schur(X, G), dense, rtol=1e-10, atol=1e-10 * np.abs(dense).max())


@pytest.mark.parametrize("builder", [ipm.lmi_problem, ipm.switched_problem])
def test_upper_triangle_assembly_is_the_full_ones(builder):
    """What the iteration factors (``upper=True``) is the upper triangle of the dense Schur complement."""
    rng = np.random.default_rng(7)
    fam = PlantFamily(F=[rng.standard_normal((4, 4)) for _ in range(3)], G=[rng.standard_normal((4, 2))] * 3)
    modes = ModeSet.from_family(fam, 2)
    coef, active = modes.scheme_coef()
    prob = builder(modes.free, coef, active)
    X, G = _rand_psd(rng, prob.nb, prob.k), _rand_psd(rng, prob.nb, prob.k)
    A = prob.dense_operator()
    dense = np.einsum("ibjk,bkl,mblo,boj->im", A, X, A, G)
    upper = prob.schur(X, G, upper=True)
    iu = np.triu_indices(prob.p)
    assert np.allclose(upper[iu], dense[iu], rtol=1e-10, atol=1e-10 * np.abs(dense).max())


def _random_block_lmi(rng, equality, objective: bool):
    """Every kind of variable and term the Schur assembly distinguishes, with dense random factors."""
    from solver.ipm.model import BlockLMI, MatrixVariable

    nb, k, q = 3, 7, 3

    def fac(a, b):
        return rng.standard_normal((nb, a, b))

    sel = np.zeros((nb, k, q))  # a 0/1 selector broadcast over the blocks (taken as an index, not a product)
    sel[:, 2:5] = np.eye(q)
    variables = [
        MatrixVariable("S", (q, q), q, [(fac(k, q), fac(q, k), 0.7), (fac(k, q), None, -0.4), (sel, None, 1.0)]),
        MatrixVariable("V", (2, q), None, [(fac(k, 2), fac(q, k), 1.3), (sel[:, :, :2], sel.transpose(0, 2, 1),
                                                                          0.5)]),
        MatrixVariable("T", (2 * q, q), q, [(fac(k, 2 * q), fac(q, k), 0.9)]),  # stacked symmetric blocks
        MatrixVariable("U", (q, q), q, [(fac(k, q), None, 1.1)]),  # sym-kind only
    ]
    C = _rand_psd(rng, nb, k)
    V0 = [np.zeros(v.shape) for v in variables]
    size = sum(v.size for v in variables)
    eq = None
    if equality:
        eq = np.zeros(size)
        eq[: q * q: q + 1] = 1.0  # trace S
        eq[q * q + 1] = 0.5 if equality == "first" else 3.0  # the eliminated coordinate: S[0, 0] or V[0, 1]
    obj = rng.standard_normal(size) if objective else None
    return BlockLMI(C=C, variables=variables, V0=V0, equality=eq, objective=obj)


@pytest.mark.parametrize("equality", [None, "first", "inner"])
@pytest.mark.parametrize("objective", [True, False])
def test_schur_of_every_variable_kind_equals_dense(equality, objective):
    """Symmetric, general, stacked-symmetric and sym-kind variables, selector and dense factors, with and
    without the equality and the t coordinate: the assembly equals ``sum_b tr(A_i X_b A_j G_b)`` from the
    explicit basis matrices."""
    rng = np.random.default_rng(11 + 2 * len(equality or "") + objective)
    prob = _random_block_lmi(rng, equality, objective)
    X, G = _rand_psd(rng, prob.nb, prob.k), _rand_psd(rng, prob.nb, prob.k)
    A = prob.dense_operator()
    dense = np.einsum("ibjk,bkl,mblo,boj->im", A, X, A, G)
    tol = 1e-10 * np.abs(dense).max()
    assert np.allclose(prob.schur(X, G), dense, rtol=1e-10, atol=tol)
    iu = np.triu_indices(prob.p)
    assert np.allclose(prob.schur(X, G, upper=True)[iu], dense[iu], rtol=1e-10, atol=tol)


def test_paper_example_primal_and_dual_match_clarabel():
    import cvxpy as cp

    from solver.methods import lmi

    modes = ModeSet.from_family(PlantFamily.paper_example(0.1), 3)
    coef, active = modes.scheme_coef()
    sol = ipm.solve_lmi(modes.free, coef, active)
    assert sol.status == "optimal"
    n, m, S, J = modes.n_states, modes.n_inputs, modes.n_modes, modes.n_free_gains
    compiled = lmi.build(n, m, S, J, active)
    values = lmi.plant_values(modes)
    compiled.solve(values)
    assert abs(sol.t - float(compiled.value("t"))) < 1e-7
    cons = compiled.problem.constraints
    assert isinstance(cons[0], cp.constraints.Equality)
    assert abs(sol.trace_multiplier - float(cons[0].dual_value)) < 1e-6
    Z = np.stack([c.dual_value for c in cons[1:]])
    assert np.abs(sol.duals - Z).max() < 1e-4  # the multipliers are unique here; both solvers stop at ~1e-8 gaps
    assert abs(np.trace(sol.duals, axis1=1, axis2=2).sum() - 1.0) < 1e-8
    assert np.linalg.eigvalsh(sol.duals)[:, 0].min() > -1e-12
    # The certificate: every block of the returned W, Y is >= t I in float64.
    assert np.isclose(np.trace(sol.W), n)


def test_dense_and_structured_paths_agree():
    modes = ModeSet.from_family(PlantFamily.paper_example(0.2), 4)
    coef, active = modes.scheme_coef()
    a = ipm.solve_lmi(modes.free, coef, active, options=ipm.IPMOptions(dense=True))
    b = ipm.solve_lmi(modes.free, coef, active, options=ipm.IPMOptions(dense=False))
    assert abs(a.t - b.t) < 1e-9 and a.status == b.status == "optimal"


#: A bounded sample of the benchmark's cross-check (python -m bench ipm-check runs >= 300).
@pytest.mark.parametrize("seed", range(1000, 1028))
def test_cross_check_against_clarabel(seed):
    row = check_one(seed, max_lmi_rows=96)
    assert row["ref_status"] == "ok" or row["status"] in ("optimal", "inaccurate"), row
    if row["ref_status"] != "ok":
        pytest.skip(f"Clarabel itself failed on {row['desc']}")
    assert row["same_verdict"], row
    assert row["diff"] <= 1e-6 or row["ref_worse"], row
    assert row["certified"] in (None, True), row


def test_switched_matches_clarabel():
    from solver.methods import lmi, switched

    rng = np.random.default_rng(7)
    fam = PlantFamily(F=[rng.standard_normal((2, 2)) for _ in range(3)], G=[rng.standard_normal((2, 1))] * 3)
    modes = ModeSet.from_family(fam, 2)
    coef, active = modes.scheme_coef()
    sol = ipm.solve_switched(modes.free, coef, active)
    compiled = switched.build(2, 1, modes.n_modes, modes.n_free_gains, active)
    values = lmi.plant_values(modes)
    compiled.solve(values)
    assert abs(sol.t - float(compiled.value("t"))) <= 1e-6 * max(1.0, abs(sol.t))
    assert abs(np.trace(sol.duals, axis1=1, axis2=2).sum() - 1.0) < 1e-8


@pytest.mark.parametrize("case", ["repeated", "zero_g", "huge", "tiny", "one_mode"])
def test_degenerate_inputs_end_with_a_status(case):
    rng = np.random.default_rng(3)
    F = rng.standard_normal((3, 3))
    G = rng.standard_normal((3, 1))
    Fs, Gs = [F, F, F], [G, G, G]
    if case == "zero_g":
        Gs = [np.zeros((3, 1))] * 3
    if case == "huge":
        Gs = [G * 1e8] * 3
    if case == "tiny":
        Fs, Gs = [F * 1e-8] * 3, [G * 1e-8] * 3
    if case == "one_mode":
        Fs, Gs = [F], [G]
    modes = ModeSet.from_family(PlantFamily(F=Fs, G=Gs), 2)
    coef, active = modes.scheme_coef()
    sol = ipm.solve_lmi(modes.free, coef, active, options=ipm.IPMOptions(max_iter=60))
    assert sol.iterations <= 60
    assert sol.status in ("optimal", "inaccurate", "max_iterations", "numerical_error")
    assert np.isfinite(sol.t)
    if sol.status in ("optimal", "inaccurate"):
        try:
            t_ref = clarabel_t(modes)
        except SolverFailed:
            return  # Clarabel gives up on these; the IPM ended with a status, which is what is asked
        assert (sol.t > MARGIN) == (t_ref > MARGIN)


def test_bad_shapes_are_a_clear_error():
    with pytest.raises(ValueError, match="free must be"):
        ipm.solve_lmi(np.zeros((2, 3, 3)), np.zeros((2, 1, 2, 1)))
    with pytest.raises(ValueError, match="finite"):
        ipm.solve_lmi(np.full((1, 2, 2), np.nan), np.zeros((1, 1, 2, 1)))


@pytest.mark.parametrize("method", ["lmi", "switched"])
def test_design_with_solver_ipm_matches_clarabel(method):
    from solver import design

    fam = PlantFamily.paper_example(0.1)
    a = design(fam, 3, method=method, solver="IPM")
    b = design(fam, 3, method=method, solver="CLARABEL")
    assert a.outcome == b.outcome == "stabilized"


def test_analyze_fixed_gain_lmi_with_ipm():
    from solver.lyapunov import common_lmi

    modes = ModeSet.from_family(PlantFamily.paper_example(0.1), 3)
    from solver import design

    gains = design(PlantFamily.paper_example(0.1), 3, method="lmi").gains
    A = modes.closed_loops(np.asarray(gains))
    X, t, info = common_lmi(A, solver="IPM")
    X2, t2, _ = common_lmi(A, solver="CLARABEL")
    assert info.solver == "IPM" and (t > 0) == (t2 > 0)
    assert np.all(np.linalg.eigvalsh(X - np.swapaxes(A, 1, 2) @ X @ A) > 0)


@pytest.mark.parametrize("seed", [1, 4])
def test_duals_are_farkas_multipliers(seed):
    """docs/design.md: Q = sum_s (Z11 + Z22 + Z21^T F_s + F_s^T Z21) = (t*/n) I and E = 0 at the optimum."""
    from bench.ipm_check import draw_case

    modes, _ = draw_case(seed)
    coef, active = modes.scheme_coef()
    sol = ipm.solve_lmi(modes.free, coef, active)
    n, Z, F = modes.n_states, sol.duals, modes.free
    Z11, Z21, Z22 = Z[:, :n, :n], Z[:, n:, :n], Z[:, n:, n:]
    Q = (Z11 + Z22 + np.swapaxes(Z21, 1, 2) @ F + np.swapaxes(F, 1, 2) @ Z21).sum(axis=0)
    E = 2 * np.einsum("sjab,sac->jbc", coef * active[:, :, None, None], Z21)
    assert np.abs(Q - sol.t / n * np.eye(n)).max() < 1e-7
    assert np.abs(E).max() < 1e-7
    assert abs(n * sol.trace_multiplier - sol.t) < 1e-7
    assert np.linalg.eigvalsh(Z)[:, 0].min() > -1e-12


def test_design_solve_congruent_decay_form():
    """The congruent decay-rate form (free_s, coef_s scaled by lambda^-eta_s) has t* > 0 iff rho-form does."""
    modes = ModeSet.from_family(PlantFamily.paper_example(0.1), 3)
    coef, _ = modes.scheme_coef()
    for lam in (0.3, 0.5):
        c = lam ** (-modes.eta.astype(float))
        _, a = ipm.design_solve(modes, "lmi", free=modes.free * c[:, None, None], coef=coef * c[:, None, None, None])
        _, b = ipm.design_solve(modes, "lmi", rho=lam ** (2.0 * modes.eta))
        assert (a.t > 1e-9) == (b.t > 1e-9)


def test_memory_is_estimated_for_the_solver_that_runs():
    """n = 50, r = 5, n_drop = 10: Clarabel's KKT would need ~10 GiB (refused), the IPM well under 1 GiB."""
    from bench.cases import random_family
    from solver.errors import InvalidInput
    from solver.methods import lmi

    modes = ModeSet.from_family(random_family(50, 5, 2, seed=0, spread=0.02), 10)
    lmi.check_size(modes, "AUTO")  # the IPM runs: accepted
    with pytest.raises(InvalidInput) as err:
        lmi.check_size(modes, "CLARABEL")
    assert "GiB" in str(err.value) and err.value.field == ("n_drop",)


def test_the_ipm_memory_estimate_covers_its_traced_peak():
    import tracemalloc

    from bench.cases import random_family
    from solver.compiled import ipm_memory

    n, r, m, N = 16, 3, 2, 4
    modes = ModeSet.from_family(random_family(n, r, m, seed=1, spread=0.05), N)
    coef, active = modes.scheme_coef()
    J, S = modes.n_free_gains, modes.n_modes
    tracemalloc.start()
    try:
        sol = ipm.solve_lmi(modes.free, coef, active)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert sol.status == "optimal"
    estimate = ipm_memory(n * n + J * m * n + 1, n * (n + 1) // 2 + J * m * n, S, 2 * n, n * n)
    assert peak <= estimate
