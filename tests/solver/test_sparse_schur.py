"""The block-sparse Schur complement of the node SDP (solver/ipm/sparse_schur.py, docs/design.md §11.4).

References: the dense Schur assembly (solver/ipm/schur.py) and numpy's dense solve for the matrix and its solves;
Clarabel through cvxpy (the same max-t SDP written as a cone program) for t*; the float64 re-check for P.
"""

import numpy as np
import pytest

from solver import Network, analyze
from solver.compiled import cp
from solver.ipm import IPMOptions
from solver.ipm.network_blocks import node_memory, node_problem, solve_node
from solver.ipm.sparse_schur import minimum_degree
from solver.network_analysis import NodeLMI, product_automaton, recheck_node_dependent

CASES = [(Network.weakly_hard(2, 5, 3), 1, "per_interval", 3),
         (Network.delays(2, 3), 1, "per_interval", 4),
         (Network.delays(1, 3), 2, "per_sample", 3)]  # two plant modes switching at every sample: a denser graph


def _states(net, modes, switching, D, seed, radius):
    prod = product_automaton(net, modes, switching)
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(prod.size, D, D))
    A = radius * A / np.abs(np.linalg.eigvals(A)).max(axis=1)[:, None, None]
    return A, prod


def _spd(rng, nb, k):
    Z = rng.normal(size=(nb, k, k))
    return Z @ np.swapaxes(Z, 1, 2) + 0.1 * np.eye(k)


def _clarabel_t(A, succ, rho):
    """``max t`` of the node SDP as a cone program (Clarabel): the independent value of t*."""
    V, D = A.shape[0], A.shape[1]
    P = [cp.Variable((D, D), symmetric=True) for _ in range(V)]
    t = cp.Variable()
    eye = np.eye(D)
    cons = [sum(cp.trace(X) for X in P) == V * D] + [X - t * eye >> 0 for X in P]
    for v in range(V):
        for w in succ[v]:
            B = rho**2 * P[v] - A[v].T @ P[w] @ A[v]
            cons.append(0.5 * (B + B.T) - t * eye >> 0)
    cp.Problem(cp.Maximize(t), cons).solve(solver=cp.CLARABEL)
    return float(t.value)


@pytest.mark.parametrize("net, modes, switching, D", CASES)
def test_the_sparse_schur_complement_is_the_dense_one(net, modes, switching, D):
    """At random positive definite X, G: the same matrix, diagonal and solves as the dense assembly (numpy solve),
    also with pinned coordinates (the dense path's zeroed rows and columns)."""
    A, prod = _states(net, modes, switching, D, 1, 1.3)
    dense, sparse = node_problem(A, prod.succ, 0.9, "dense"), node_problem(A, prod.succ, 0.9, "sparse")
    rng = np.random.default_rng(2)
    X, G = _spd(rng, dense.nb, dense.k), _spd(rng, dense.nb, dense.k)
    M = dense.schur(X, G)
    S = sparse.schur(X, G)
    scale = np.abs(M).max()
    assert np.abs(S.dense() - M).max() <= 1e-12 * scale
    assert np.abs(S.diagonal() - np.diag(M)).max() <= 1e-12 * scale
    h = rng.normal(size=(M.shape[0],))
    dead = np.zeros(M.shape[0], dtype=bool)
    dead[[1, 5, M.shape[0] // 2]] = True
    Mp = M.copy()
    Mp[dead, :] = 0.0
    Mp[:, dead] = 0.0
    Mp[dead, dead] = 1.0
    hp = np.where(dead, 0.0, h)
    for pins, ref in ((None, np.linalg.solve(M, h)), (dead, np.linalg.solve(Mp, hp))):
        solve = sparse.schur(X, G).factor(pins)
        got = solve(h if pins is None else hp)
        assert np.abs(got - ref).max() <= 1e-8 * np.abs(ref).max()


@pytest.mark.parametrize("net, modes, switching, D", CASES)
@pytest.mark.parametrize("rho, radius", [(1.0, 0.9), (0.8, 0.9), (1.0, 1.6)])
def test_node_sdp_sparse_dense_and_clarabel_agree(net, modes, switching, D, rho, radius):
    """t* of the block-sparse IPM = the dense IPM's = Clarabel's (to 1e-6), feasible and infeasible cases; the
    sparse path's P passes the float64 re-check exactly when t* > 0."""
    A, prod = _states(net, modes, switching, D, 3, radius)
    ts, Ps, st_s = solve_node(A, prod.succ, rho, IPMOptions(dense=False), schur="sparse")
    td, _, st_d = solve_node(A, prod.succ, rho, IPMOptions(dense=False), schur="dense")
    tc = _clarabel_t(A, prod.succ, rho)
    assert st_s == st_d == "optimal"
    assert abs(ts - td) <= 1e-6 * max(1.0, abs(td))
    assert abs(ts - tc) <= 1e-6 * max(1.0, abs(tc))
    if abs(ts) > 1e-6:
        assert recheck_node_dependent(Ps, A, prod, rho).verified == (ts > 0)


def test_analysis_verdict_and_rate_on_the_sparse_ipm_dense_ipm_and_clarabel(monkeypatch):
    """analyze(network=) on the IPM: the same verdict and CJSR upper bound with the block-sparse and the dense Schur
    complement (to 1e-6), the same verdict as Clarabel and its bound within 2 % (near the bound the bisection's
    probes may be decided differently by the two solvers' P; measured 1.1 % on weakly_hard(1, 3, 2))."""
    import solver.ipm.network_blocks as blocks
    from solver import PlantFamily
    from tests.solver.test_network_analysis import DELAY_FAMILY, DELAY_GAINS

    fam = PlantFamily(**DELAY_FAMILY)
    for net in (Network.weakly_hard(1, 3, 2), Network.delays(1, 2)):
        monkeypatch.setattr(blocks, "SPARSE_NODE_FROM", 1)  # the block-sparse path, whatever the state count
        ipm = analyze(fam, DELAY_GAINS, network=net, solver="IPM")
        monkeypatch.setattr(blocks, "SPARSE_NODE_FROM", 10**9)
        dense = analyze(fam, DELAY_GAINS, network=net, solver="IPM")
        monkeypatch.undo()
        cla = analyze(fam, DELAY_GAINS, network=net, solver="CLARABEL")
        assert ipm.stable == dense.stable == cla.stable
        assert (ipm.jsr_upper_bound is None) == (dense.jsr_upper_bound is None) == (cla.jsr_upper_bound is None)
        if ipm.jsr_upper_bound is not None:
            assert abs(ipm.jsr_upper_bound - dense.jsr_upper_bound) <= 1e-6 * dense.jsr_upper_bound
            assert abs(ipm.jsr_upper_bound - cla.jsr_upper_bound) <= 2e-2 * cla.jsr_upper_bound
        if ipm.stable:
            assert ipm.certificate.verified and ipm.certificate.source.startswith("node_lmi")


def test_a_64_node_automaton_runs_on_the_ipm():
    """weakly_hard(3, 8, 4) (64 states) at D = 8: "AUTO" solves on the IPM (its memory estimate fits), the P re-checks
    in float64, and t* is Clarabel's; the estimate is below the dense Schur complement's."""
    A, prod = _states(Network.weakly_hard(3, 8, 4), 1, "per_interval", 8, 5, 0.5)
    assert prod.size == 64
    lmi = NodeLMI(A, prod)
    P = lmi.solve(1.0, "AUTO")
    assert lmi.ipm_solves == 1 and P is not None
    assert recheck_node_dependent(P, A, prod).verified
    t, _, status = solve_node(A, prod.succ)
    assert status == "optimal"
    assert abs(t - _clarabel_t(A, prod.succ, 1.0)) <= 1e-6
    assert node_memory(prod.succ, 8) < node_memory(prod.succ, 8, "dense") / 10


def test_the_node_memory_estimate_covers_the_traced_peak():
    """tracemalloc's peak of the sparse solve (weakly_hard(2, 5, 3), D = 8) is below node_memory."""
    import tracemalloc

    A, prod = _states(Network.weakly_hard(2, 5, 3), 1, "per_interval", 8, 6, 0.9)
    tracemalloc.start()
    solve_node(A, prod.succ, schur="sparse")
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak <= node_memory(prod.succ, 8)


def test_minimum_degree_gives_a_closed_elimination_structure():
    """Every column's fill is in the columns it updates (brute force: eliminating in that order creates no edge
    outside ``below``), and every graph edge is in the structure."""
    rng = np.random.default_rng(7)
    V = 30
    pairs = [(int(a), int(b)) for a, b in rng.integers(0, V, size=(60, 2))]
    order, below = minimum_degree(V, pairs)
    pos = np.empty(V, dtype=int)
    pos[order] = np.arange(V)
    have = {(k, i) for k, rows in enumerate(below) for i in rows}
    for u, v in pairs:
        if u != v:
            assert (min(pos[u], pos[v]), max(pos[u], pos[v])) in have
    for k, rows in enumerate(below):
        for a in rows:
            for b in rows:
                if a < b:
                    assert (a, b) in have


def test_edge_problem_with_parallel_edges_matches_clarabel():
    """:func:`edge_problem` (the fixed-gain node SDP of a network design: a map and a rate per edge, two edges
    between the same nodes with different maps): ``t*`` of the dense and the sparse Schur complement and of Clarabel
    agree, infeasible (squared rates near 1: t* = -0.27) and feasible (4: t* = 0.83)."""
    import cvxpy as cp

    from solver.ipm import IPMOptions
    from solver.ipm.algorithm import solve_block_lmi
    from solver.ipm.network_blocks import edge_problem

    rng = np.random.default_rng(1)
    V, D = 5, 4
    src, dst, A = [], [], []
    for v in range(V):
        for w in rng.choice(V, 2, replace=False):
            for _ in range(2):
                src.append(v)
                dst.append(int(w))
                M = rng.standard_normal((D, D))
                A.append(0.8 * M / max(abs(np.linalg.eigvals(M))))
    src, dst, A = np.array(src), np.array(dst), np.array(A)
    for rho2, sign in ((rng.uniform(0.9, 1.1, len(src)), -1), (np.full(len(src), 4.0), 1)):
        # dense=False: the Kronecker path, where the sparse structure is used (small problems take the dense operator)
        ts = [solve_block_lmi(edge_problem(A, src, dst, V, rho2, schur=s), IPMOptions(dense=False)).t
              for s in ("dense", "sparse")]
        P = [cp.Variable((D, D), symmetric=True) for _ in range(V)]
        t = cp.Variable()
        cons = [sum(cp.trace(X) for X in P) == V * D] + [X - t * np.eye(D) >> 0 for X in P]
        for e in range(len(src)):
            M = rho2[e] * P[src[e]] - A[e].T @ P[dst[e]] @ A[e]
            cons.append(0.5 * (M + M.T) - t * np.eye(D) >> 0)
        cp.Problem(cp.Maximize(t), cons).solve(solver="CLARABEL")
        assert ts[0] == pytest.approx(t.value, abs=1e-6) and ts[1] == pytest.approx(t.value, abs=1e-6)
        assert np.sign(ts[0]) == sign
