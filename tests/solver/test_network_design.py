"""design(..., network=net) against independent references: brute-force products over admissible cycles,
random admissible sequences stepped sample by sample, exact arithmetic on an unstable cycle."""

import itertools
from fractions import Fraction
from math import gcd

import numpy as np
import pytest

from bench.network_bench import badly_scaled
from solver import InvalidInput, Network, PlantFamily, analyze, design, exact
from solver.compiled import design_size
from solver.methods import network_lmi

from .paper_data import EQ20_F, EQ20_G

# A plant whose drop-only design (n_drop = 2) is certified, but a one-sample delay destabilizes it.
DELAY_FAMILY = PlantFamily([[[0.19, -0.52], [-0.41, -2.44]]], [[[1.8], [1.14]]])


def step(F, G, K, hist, d, l):
    """One sample of the buffer: x(t+1) = F_l x(t) + G_l K_{d+1} x(t-d); hist[i] = x(t-i)."""
    return [F[l] @ hist[0] + G[l] @ K[d] @ hist[d]] + hist[:-1]


def cycle_product(F, G, K, ages, modes):
    """xi(0) -> xi(len) over one period, stepped on unit vectors (independent of solver.networks)."""
    N, n = K.shape[0], F.shape[-1]
    cols = []
    for e in np.eye(n * N):
        hist = [e[i * n:(i + 1) * n] for i in range(N)]
        for d, l in zip(ages, modes):
            hist = step(F, G, K, hist, d, l)
        cols.append(np.concatenate(hist))
    return np.array(cols).T


def admissible_cycles(net, n_plants, length):
    """Every periodic admissible (ages, plant modes) of period ``length``; plant modes change at fresh packets."""
    for ages in itertools.product(range(net.n_drop), repeat=length):
        if not net.admissible(list(ages) * (net.nodes + 2)):
            continue
        for modes in itertools.product(range(n_plants), repeat=length):
            if all(modes[t] == modes[t - 1] or ages[t] <= ages[t - 1] for t in range(length)):
                yield ages, modes


def max_cycle_rate(fam, K, net, longest):
    """max over admissible cycles of rho(product)^(1/length): a lower bound of the constrained JSR."""
    F, G = np.asarray(fam.F), np.asarray(fam.G)
    best = 0.0
    for length in range(1, longest + 1):
        for ages, modes in admissible_cycles(net, fam.n_modes, length):
            rho = max(abs(np.linalg.eigvals(cycle_product(F, G, K, ages, modes))))
            best = max(best, rho ** (1.0 / length))
    return best


def random_runs_decay(fam, K, net, runs=100, steps=300, seed=1):
    """Largest ||xi(steps)|| / ||xi(0)|| over random admissible runs (random walks on the automaton)."""
    rng = np.random.default_rng(seed)
    F, G = np.asarray(fam.F), np.asarray(fam.G)
    N, n = K.shape[0], fam.n_states
    worst = 0.0
    for _ in range(runs):
        node = int(rng.integers(net.nodes))
        hist = [rng.normal(size=n) for _ in range(N)]
        start = np.linalg.norm(np.concatenate(hist))
        l = int(rng.integers(fam.n_modes))
        ages = []
        for _ in range(steps):
            d = int(net.ages[node])
            ages.append(d)
            hist = step(F, G, K, hist, d, l)
            node = int(rng.choice(net.successors(node)))
            if net.ages[node] <= d:  # a fresh packet: the plant mode may jump
                l = int(rng.integers(fam.n_modes))
        assert net.admissible(ages)
        worst = max(worst, np.linalg.norm(np.concatenate(hist)) / start)
    return worst


def exact_char_poly(M):
    """Exact characteristic polynomial coefficients of a small rational matrix (Faddeev-LeVerrier)."""
    n = len(M)
    A = [[Fraction(x) for x in row] for row in M]
    coeffs = [Fraction(1)]
    Mk = [[Fraction(0)] * n for _ in range(n)]
    for k in range(1, n + 1):
        AM = [[sum(A[i][p] * Mk[p][j] for p in range(n)) for j in range(n)] for i in range(n)]
        c_prev = coeffs[-1]
        Mk = [[AM[i][j] + (c_prev if i == j else 0) for j in range(n)] for i in range(n)]
        AM = [[sum(A[i][p] * Mk[p][j] for p in range(n)) for j in range(n)] for i in range(n)]
        coeffs.append(-sum(AM[i][i] for i in range(n)) / k)
    return coeffs  # det(zI - A) = sum coeffs[k] z^(n-k)


# --------------------------------------------------------------------------------------------- (a) delays
def test_delay_destabilizes_the_drop_only_design_and_the_delay_aware_design_is_certified():
    drop_only = design(DELAY_FAMILY, 2, decay_rate=None)
    assert drop_only.outcome == "stabilized"
    net = Network.delays(1, 2)
    # the age stays 1 forever (every packet one sample late) is admissible for delays(1, 2), not for the paper's
    assert net.admissible([1] * 10) and not Network.bounded_drops(2).admissible([1, 1])
    K = drop_only.gains
    A1 = cycle_product(np.asarray(DELAY_FAMILY.F), np.asarray(DELAY_FAMILY.G), K, (1,), (0,))
    # exact: the characteristic polynomial of the rational (float64-exact) product has a real root above 1:
    # p(1) and p(+inf) (or p(-1), p(-inf)) of different signs
    c = exact_char_poly([[Fraction(float(x)) for x in row] for row in A1])
    p = lambda z: sum(ck * z ** (len(c) - 1 - k) for k, ck in enumerate(c))  # noqa: E731
    assert p(Fraction(1)) < 0 or p(Fraction(-1)) * (-1) ** (len(c) - 1) < 0
    rep = analyze(DELAY_FAMILY, K, network=net)
    assert rep.stable is False and rep.unstable_cycle is not None

    res = design(DELAY_FAMILY, network=net, decay_rate=None)
    assert res.outcome == "stabilized", res.message
    assert res.gains.shape == (2, 1, 2) and res.network == net.to_dict()
    assert analyze(DELAY_FAMILY, res.gains, network=net).stable is True
    # independent references: every admissible cycle up to length 8 contracts, random runs decay
    assert max_cycle_rate(DELAY_FAMILY, res.gains, net, 8) < 1.0
    assert random_runs_decay(DELAY_FAMILY, res.gains, net, runs=60, steps=600) < 1e-3


# ------------------------------------------------------------------------------------------ (c) bounded_drops
def test_bounded_drops_network_reproduces_the_paper_design():
    fam = PlantFamily(list(EQ20_F), list(EQ20_G), sampling_period=0.1)
    for kwargs in ({"decay_rate": None}, {}):
        today = design(fam, 3, **kwargs)
        net = design(fam, network=Network.bounded_drops(3), **kwargs)
        assert today.outcome == net.outcome == "stabilized"
        np.testing.assert_allclose(net.gains, today.gains, rtol=1e-6, atol=1e-9)
        assert net.method == today.method == "lmi" and net.network == {"kind": "bounded_drops", "n_drop": 3}
    same = design(fam, 3, network={"kind": "bounded_drops", "n_drop": 3}, decay_rate=None)
    np.testing.assert_allclose(same.gains, design(fam, 3, decay_rate=None).gains, rtol=1e-6, atol=1e-9)


def test_lifted_network_lmi_on_bounded_drops_contains_the_lmi_design():
    """Forced through the network method, bounded drops is the lmi design with node = one matrix."""
    fam = PlantFamily(list(EQ20_F), list(EQ20_G), sampling_period=0.1)
    net = Network.bounded_drops(3)
    res = network_lmi.run(fam, net)
    assert res.outcome == "stabilized"
    assert network_lmi.build_problem(fam, net).form == "lifted"
    assert max_cycle_rate(fam, res.gains, net, 5) < 1.0


# ------------------------------------------------------------------------------------------------ outcomes
def test_n_drop_must_agree_with_the_network():
    with pytest.raises(InvalidInput) as err:
        design(DELAY_FAMILY, 3, network=Network.delays(1, 2))
    assert err.value.field == ("n_drop",)
    with pytest.raises(InvalidInput):
        design(DELAY_FAMILY)


@pytest.mark.parametrize("kwargs,field", [({"method": "switched"}, "method"), ({"scheme": "hold"}, "scheme")])
def test_unsupported_options_on_a_network_are_refused(kwargs, field):
    with pytest.raises(InvalidInput) as err:
        design(DELAY_FAMILY, network=Network.delays(1, 2), **kwargs)
    assert err.value.field[0] == field and "not supported yet for network=" in str(err.value)


def test_uncontrollable_unstable_mode_is_infeasible_on_any_network():
    fam = PlantFamily([[[1.5, 0.0], [0.0, 0.5]]], [[[0.0], [1.0]]])
    res = design(fam, network=Network.delays(1, 2), decay_rate=None)
    assert res.outcome == "infeasible" and res.certificate.kind == "uncontrollable" and res.gains is None


def test_not_certified_carries_a_farkas_certificate_of_the_network_lmi():
    """A scalar plant too unstable for any gain on weakly_hard(1, 3, 3): the convex condition is proven empty.

    x+ = 4 x + 0.1 u with intervals of 1..3 samples: the Farkas multipliers are re-checked in float64, and
    the outcome is not "infeasible" (weakly_hard(1, 3, 3) does not contain every bounded_drops run).
    """
    fam = PlantFamily([[[4.0]], [[-4.0]]], [[[0.1]], [[0.1]]])
    net = Network.weakly_hard(1, 3, 3)
    assert not network_lmi.contains_bounded_drops(net)
    res = design(fam, network=net, decay_rate=None, max_iter=3)
    assert res.outcome == "not_certified" and res.gains is None
    assert res.certificate.verified and res.certificate.delta > 0
    assert res.to_dict()["certificate"]["kind"] == "farkas_network"
    assert "not every gain" in res.message
    prob = network_lmi.build_problem(fam, net)
    again = network_lmi.check_network_farkas(prob, res.certificate.multipliers, np.ones(prob.n_blocks))
    assert again.verified
    # the multipliers negated are no certificate: the re-check must say so
    bad = [-M for M in res.certificate.multipliers]
    assert not network_lmi.check_network_farkas(prob, bad, np.ones(prob.n_blocks)).verified


def test_containment_of_bounded_drops_runs():
    assert network_lmi.contains_bounded_drops(Network.delays(1, 3))
    assert network_lmi.contains_bounded_drops(Network.bounded_drops(3))
    assert not network_lmi.contains_bounded_drops(Network.weakly_hard(2, 5, 3))
    assert not network_lmi.contains_bounded_drops(Network.delays(2, 3, min_delay=1))
    # brute force on words of length 7
    for net in (Network.delays(1, 3), Network.weakly_hard(2, 5, 3), Network.delays(2, 3, min_delay=1)):
        bd = Network.bounded_drops(3)
        words = [w for w in itertools.product(range(3), repeat=7) if bd.admissible(list(w))]
        assert network_lmi.contains_bounded_drops(net) == all(net.admissible(list(w)) for w in words)


# ------------------------------------------------------------------------------------------------ limits
def test_design_size_counts_nodes_plant_modes_and_the_augmented_state():
    small = design_size("lmi", 2, 1, 1, 3, network=Network.delays(1, 3))
    assert small.nodes == Network.delays(1, 3).nodes and small.state_size == 6
    bigger = design_size("lmi", 2, 1, 3, 3, network=Network.delays(1, 3))
    assert bigger.n_modes == 3 * small.n_modes and bigger.memory > small.memory
    lifted = design_size("lmi", 2, 1, 1, 3, network=Network.weakly_hard(2, 5, 3))
    assert lifted.state_size == 2  # every packet that takes effect is fresh: the lifted form on x
    assert design_size("lmi", 2, 1, 1, 3, network=Network.bounded_drops(3)) == design_size("lmi", 2, 1, 1, 3)


def test_too_large_network_design_is_refused_up_front_naming_nodes_and_memory():
    fam = PlantFamily([np.eye(10) * 0.5] * 3, [np.ones((10, 2))] * 3)
    net = Network.delays(4, 8)
    with pytest.raises(InvalidInput) as err:
        design(fam, network=net, decay_rate=None)
    text = str(err.value)
    assert "automaton nodes" in text and "LMI size" in text and ("memory" in text or " s " in text)
    with pytest.raises(InvalidInput) as err:
        design(fam, network=net, decay_rate=None, max_memory=2**20, time_limit=10)
    assert "memory" in str(err.value) and "MiB" in str(err.value)


# ------------------------------------------------------------------------------------------------ (b) weakly hard
# x+ = 1.3 x + b_l u, b in {1.5, 0.5}: min over gains of max_l |A_{l,eta}| = 1.3^eta (3 - 1)/(3 + 1) in closed form
# (the interval maps' gain terms c_eta are free per eta): 0.65, 0.845, 1.0985 for eta = 1, 2, 3.
WEAKLY_HARD_FAMILY = PlantFamily([[[1.3]], [[1.3]]], [[[1.5]], [[0.5]]])


def test_no_design_for_bounded_drops_3_but_one_for_weakly_hard_2_5_3():
    a, b = 1.3, (1.5, 0.5)
    best3 = a**3 * (b[0] / b[1] - 1) / (b[0] / b[1] + 1)
    assert best3 > 1  # closed form: every gain leaves a plant mode whose 3-sample interval map has |A| > 1
    none = design(WEAKLY_HARD_FAMILY, 3, decay_rate=None)
    assert none.outcome == "infeasible" and none.certificate.kind == "farkas" and none.certificate.any_margin
    net = Network.weakly_hard(2, 5, 3)
    res = design(WEAKLY_HARD_FAMILY, network=net, decay_rate=None)
    assert res.outcome == "stabilized", res.message
    assert analyze(WEAKLY_HARD_FAMILY, res.gains, network=net).stable is True
    # the 3-sample interval still expands for some plant mode: the window constraint is what saves the loop
    A3 = [a**3 + sum(a**t * bl * res.gains[2 - t][0, 0] for t in range(3)) for bl in b]
    assert max(abs(x) for x in A3) > 1
    assert max_cycle_rate(WEAKLY_HARD_FAMILY, res.gains, net, 8) < 1.0
    assert random_runs_decay(WEAKLY_HARD_FAMILY, res.gains, net, runs=60, steps=400) < 1e-3


def test_infeasible_carries_over_to_a_network_that_admits_every_bounded_drops_run():
    net = Network.delays(1, 3)
    assert network_lmi.contains_bounded_drops(net)
    res = design(WEAKLY_HARD_FAMILY, network=net, decay_rate=None, max_iter=2)
    assert res.outcome == "infeasible" and res.certificate.kind == "farkas"
    assert "admits every run of bounded_drops(3)" in res.message
    # the converse direction is not used: weakly_hard(2, 5, 3) is designed above although bounded_drops(3) is not


@pytest.mark.parametrize("request_", [{"objective": "cost"}, {"objective": "cost", "x0": [1.0]},
                                      {"objective": "hinf", "disturbance": [[1.0]]}], ids=["cost", "cost_x0", "hinf"])
def test_a_performance_design_carries_the_same_proof(request_):
    # every gain leaves an expanding 3-sample interval (closed form above), so no gain has a finite cost or l2 gain
    # on delays(1, 3); the performance design answers with the stability design's re-checked proof ("not_certified"
    # before: its own SDP's Farkas certificate excludes only its form)
    net = Network.delays(1, 3)
    res = design(WEAKLY_HARD_FAMILY, network=net, **request_)
    assert res.outcome == "infeasible" and res.certificate.kind == "farkas" and res.gains is None, res.message
    assert res.objective == request_["objective"] and res.network is not None
    assert "admits every run of bounded_drops(3)" in res.message and "the same proof" in res.message


def test_decay_rate_on_a_network_bounds_every_admissible_cycle():
    net = Network.weakly_hard(2, 5, 3)
    res = design(WEAKLY_HARD_FAMILY, network=net, decay_rate="max", rate_tol=1e-2)
    assert res.outcome == "stabilized" and 0 < res.decay_rate < 1
    assert res.certificate.kind == "node_dependent" and res.certificate.form == "lifted"
    assert res.rate_bracket["lower"] <= res.decay_rate == res.rate_bracket["upper"]
    # a certified per-sample rate lambda bounds every admissible cycle's rho(product)^(1/length)
    assert max_cycle_rate(WEAKLY_HARD_FAMILY, res.gains, net, 8) <= res.decay_rate * (1 + 1e-9)
    fixed = design(WEAKLY_HARD_FAMILY, network=net, decay_rate=0.5 * (1 + res.decay_rate))
    assert fixed.outcome == "stabilized" and fixed.settling is not None


def test_per_sample_plant_switching_on_the_paper_motor():
    """Lifted form with per-sample plant sequences (sum 3^eta loop modes per path), re-checked by the analysis."""
    fam = PlantFamily(list(EQ20_F), list(EQ20_G), sampling_period=0.1)
    net = Network.weakly_hard(2, 5, 3)
    res = design(fam, network=net, decay_rate=None, plant_switching="per_sample")
    assert res.outcome == "stabilized" and "lifted form" in res.message
    assert analyze(fam, res.gains, network=net, plant_switching="per_sample").stable is True
    assert random_runs_decay(fam, res.gains, net, runs=30, steps=300) < 1e-3


def exact_positive_definite(M):
    """Whether the symmetric rational matrix M is positive definite: LDL' pivots in exact arithmetic."""
    A = [[Fraction(x) for x in row] for row in M]
    n = len(A)
    for k in range(n):
        if A[k][k] <= 0:
            return False
        for i in range(k + 1, n):
            f = A[i][k] / A[k][k]
            for j in range(k, n):
                A[i][j] -= f * A[k][j]
    return True


def test_network_design_balances_badly_scaled_plants_and_proves_the_users_loop():
    """The network design runs in balanced coordinates (docs/design.md §11.1, "Scaling"): on a badly scaled copy of
    a random family it is certified, in the user's coordinates, where the unbalanced design found nothing."""
    from bench.cases import random_family

    net = Network.weakly_hard(1, 3, 2)
    fam = badly_scaled(random_family(3, 2, 1, seed=1), 1)
    unbalanced = design(fam, network=net, decay_rate=None, scaling="none")
    assert unbalanced.outcome != "stabilized"
    res = design(fam, network=net, decay_rate=None)
    assert res.outcome == "stabilized", res.message
    assert res.scaling["certificate"] == "original" and len(res.scaling["state"]) == 3
    # the node certificate re-checked in exact arithmetic on the user's loop (every transition of the automaton)
    prob = network_lmi.build_problem(fam, net)
    A = prob.closed_loops(res.gains)
    P = [[[Fraction(float(x)) for x in row] for row in M] for M in 0.5 * (res.certificate.P +
                                                                          np.swapaxes(res.certificate.P, 1, 2))]
    assert all(exact_positive_definite(M) for M in P)
    for e in range(prob.n_blocks):
        Ae = [[Fraction(float(x)) for x in row] for row in A[e]]
        k = len(Ae)
        Pw = P[prob.dst[e]]
        APA = [[sum(Ae[p][i] * Pw[p][q] * Ae[q][j] for p in range(k) for q in range(k)) for j in range(k)]
               for i in range(k)]
        assert exact_positive_definite([[P[prob.src[e]][i][j] - APA[i][j] for j in range(k)] for i in range(k)])
    # independent of the automaton's transition matrices: admissible cycles and random runs, sample by sample
    assert max_cycle_rate(fam, res.gains, net, 6) < 1.0
    assert random_runs_decay(fam, res.gains, net, runs=40, steps=400) < 1e-3
    # a delays network on the same plant: stabilized, by a certificate in one of the two coordinates
    delays = design(fam, network=Network.delays(1, 2), decay_rate=None)
    assert delays.outcome == "stabilized", delays.message
    assert max_cycle_rate(fam, delays.gains, Network.delays(1, 2), 6) < 1.0


# ------------------------------------------------------------------------------------- fixed-rate fallback
def exact_augmented(F, G, K, d):
    """A[d] on xi = (x(t), ..., x(t-N+1)) in Fractions, from x(t+1) = F x(t) + G K_(d+1) x(t-d) (not loop_matrices)."""
    n, N = F.shape[0], K.shape[0]
    Fq = exact.fractions(F)
    Gq, Kq = exact.fractions(G), exact.fractions(K[d])
    GKq = [[sum(Gq[i][p] * Kq[p][j] for p in range(len(Kq))) for j in range(n)] for i in range(n)]
    A = [[Fraction(0)] * (n * N) for _ in range(n * N)]
    for i in range(n):
        for j in range(n):
            A[i][j] += Fq[i][j]
            A[i][d * n + j] += GKq[i][j]
    for i in range(n, n * N):  # the shift x(t-i) -> x(t-i-1)
        A[i][i - n] = Fraction(1)
    return A


def exactly_positive_definite(M):
    """Sylvester's criterion on the integer matrix (common denominator) of a symmetric Fraction matrix."""
    den = 1
    for row in M:
        for x in row:
            den = den * x.denominator // gcd(den, x.denominator)
    return exact.positive_definite_integer([[x * den for x in row] for row in M])


def own_recheck_fails(monkeypatch):
    """Every re-check of the design's own node matrices (``run``'s, source "network_lmi") fails; CCL's fixed-gain
    node SDP (source "network_analysis") keeps the real one."""
    real = network_lmi.recheck_network

    def recheck(prob, P, gains, rate=None, source="network_lmi"):
        cert = real(prob, P, gains, rate, source)
        if source == "network_lmi":
            cert.verified = False
        return cert

    monkeypatch.setattr(network_lmi, "recheck_network", recheck)


def exact_matmul(A, B):
    return [[sum(A[r][p] * B[p][c] for p in range(len(B))) for c in range(len(B[0]))] for r in range(len(A))]


def exactly_decreasing(Pv, Pw, A, rho2):
    """``rho2 P_v - A' P_w A`` positive definite, in Fractions."""
    At = [list(col) for col in zip(*A)]
    APA = exact_matmul(At, exact_matmul(Pw, A))
    return exactly_positive_definite([[rho2 * Pv[r][c] - APA[r][c] for c in range(len(A))] for r in range(len(A))])


def exact_symmetric(M):
    """The symmetric part of a float64 matrix, exactly."""
    Q = exact.fractions(M)
    return [[(Q[r][c] + Q[c][r]) / 2 for c in range(len(Q))] for r in range(len(Q))]


def reception_paths(net):
    """(v, w, eta): a packet received at node v (age 0), the next one at w, eta samples later, the ages between
    them 1, ..., eta - 1 (walked on the automaton's successors, not network_lmi.lifted_edges)."""
    out = set()
    for v in range(net.nodes):
        if net.ages[v] != 0:
            continue
        walk = [(v, 1)]
        while walk:
            u, eta = walk.pop()
            for w in net.successors(u):
                if net.ages[w] == 0:
                    out.add((v, w, eta))
                elif net.ages[w] == eta:
                    walk.append((w, eta + 1))
    return out


def test_fixed_rate_fallback_certifies_the_lmi_gains_when_their_own_node_matrices_fail(monkeypatch):
    """docs/design.md §11.1, "Fixed-rate fallback": the design's own node matrices fail the re-check (forced), the
    fixed-gain node SDP in the design's (lifted) form certifies the same gains at the same rate, before CCL (which
    would otherwise answer, with other gains: method "network_ccl")."""
    own_recheck_fails(monkeypatch)
    net, rate = Network.weakly_hard(2, 5, 3), 0.95
    res = design(WEAKLY_HARD_FAMILY, network=net, decay_rate=rate)
    assert res.outcome == "stabilized" and res.method == "network_lmi", res.message
    assert "failed the float64 re-check" in res.message and "fixed-gain node analysis" in res.message
    cert = res.certificate
    assert cert.kind == "node_dependent" and cert.verified and cert.form == "lifted" and res.decay_rate == rate
    # independent re-check in exact arithmetic on the float64 numbers: for every reception-to-reception path of eta
    # samples and plant mode l (constant between receptions), the interval map
    # x -> (F^eta + sum_t F^(eta-1-t) G K_(t+1)) x satisfies rate^(2 eta) P_v - A' P_w A > 0 exactly
    F, G, K = np.asarray(WEAKLY_HARD_FAMILY.F), np.asarray(WEAKLY_HARD_FAMILY.G), np.asarray(res.gains)
    index = {int(v): i for i, v in enumerate(cert.nodes)}
    assert sorted(index) == [v for v in range(net.nodes) if net.ages[v] == 0]
    P = [exact_symmetric(M) for M in cert.P]
    paths = reception_paths(net)
    assert {eta for _, _, eta in paths} == {1, 2, 3}
    for v in index:
        assert exactly_positive_definite(P[index[v]])
    for v, w, eta in paths:
        for l in range(2):
            Fq, Gq = exact.fractions(F[l]), exact.fractions(G[l])
            n = len(Fq)
            power = [[Fraction(int(r == c)) for c in range(n)] for r in range(n)]  # F^(eta-1-t), t from eta-1 down
            A = [[Fraction(0)] * n for _ in range(n)]
            for t in reversed(range(eta)):
                GK = exact_matmul(exact_matmul(power, Gq), exact.fractions(K[t]))
                A = [[A[r][c] + GK[r][c] for c in range(n)] for r in range(n)]
                power = exact_matmul(power, Fq)
            A = [[A[r][c] + power[r][c] for c in range(n)] for r in range(n)]  # power = F^eta
            assert exactly_decreasing(P[index[v]], P[index[w]], A, Fraction(rate) ** (2 * eta)), (v, w, eta, l)
    assert random_runs_decay(WEAKLY_HARD_FAMILY, res.gains, net, runs=30, steps=300) < 1e-3


def test_fixed_rate_fallback_on_the_product_automaton(monkeypatch):
    """When the design-form node SDP certifies nothing either (forced), the node analysis on the product automaton
    (augmented state, one P per node and plant mode) certifies the gains: re-checked exactly."""
    own_recheck_fails(monkeypatch)
    monkeypatch.setattr(network_lmi, "node_analysis", lambda *args, **kwargs: None)
    net, rate = Network.weakly_hard(2, 5, 3), 0.95
    res = design(WEAKLY_HARD_FAMILY, network=net, decay_rate=rate, max_iter=1)
    assert res.outcome == "stabilized" and res.method == "network_lmi", res.message
    assert "fixed-gain node analysis" in res.message and "plant mode on the augmented state" in res.message
    cert = res.certificate
    assert cert.kind == "node_dependent" and cert.verified and cert.decay_rate == rate
    # states (node, plant mode), edges rebuilt from the automaton (the plant switches only where a fresh packet
    # arrives), rate^2 P_v - A_v' P_w A_v > 0 exactly with A_v built from x(t+1) = F x(t) + G K_(d+1) x(t-d)
    F, G, K = np.asarray(WEAKLY_HARD_FAMILY.F), np.asarray(WEAKLY_HARD_FAMILY.G), np.asarray(res.gains)
    states = [tuple(s) for s in cert.states]
    assert sorted(states) == [(i, l) for i in range(net.nodes) for l in range(2)]
    index = {s: v for v, s in enumerate(states)}
    P = [exact_symmetric(M) for M in cert.P]
    edges = 0
    for (i, l), v in index.items():
        A = exact_augmented(F[l], G[l], K, int(net.ages[i]))
        assert exactly_positive_definite(P[v])
        for j in net.successors(i):
            for l2 in range(2):
                if l2 != l and net.ages[j] > net.ages[i]:
                    continue
                assert exactly_decreasing(P[v], P[index[(j, l2)]], A, Fraction(rate) ** 2), (i, l, j, l2)
                edges += 1
    assert edges > len(states)
    assert random_runs_decay(WEAKLY_HARD_FAMILY, res.gains, net, runs=30, steps=300) < 1e-3


def test_rate_search_steps_skip_the_fixed_rate_fallback(monkeypatch):
    """A rate search's probe (``rate_search=True``) is decided by the SDP's own candidate alone."""
    own_recheck_fails(monkeypatch)
    calls = []
    real = network_lmi.node_analysis

    def counted(*args, **kwargs):
        calls.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(network_lmi, "node_analysis", counted)
    net = Network.weakly_hard(2, 5, 3)
    probe = network_lmi.run(WEAKLY_HARD_FAMILY, net, decay_rate=0.95, use_ccl=False, rate_search=True)
    assert probe.outcome != "stabilized" and not calls
    fixed = network_lmi.run(WEAKLY_HARD_FAMILY, net, decay_rate=0.95, use_ccl=False)
    assert fixed.outcome == "stabilized" and calls


def test_a_rate_the_solvers_give_up_on_is_a_failed_step_of_the_default_search():
    """Hold-out draw_family 9818 (two identical 2-state modes, three inputs: nearly deadbeat) on weakly_hard(1, 3, 3):
    the default's search certified rates down to 0.011, then a probe at 0.0016 made both solvers give up (IPM
    max_iterations, Clarabel failed: the blocks carry rate^-3 ~ 2e8) and the SolverFailed ended the design as
    "not_converged".  Now that probe is a failed step: the search goes on, the design at the target is certified, and
    the independent network analysis finds the gains stable."""
    from bench.ipm_check import draw_family

    fam, _, _ = draw_family(9818, max_n=8, max_lmi_rows=200)
    net = Network.weakly_hard(1, 3, 3)
    res = design(fam, network=net)
    assert res.outcome == "stabilized", res.message
    failed = [t for t in res.rate_search if t["outcome"] == "not_converged"]
    assert failed and all(t["decay_rate"] < res.rate_bracket["upper"] for t in failed)
    assert res.decay_rate >= res.rate_bracket["upper"]
    assert analyze(fam, res.gains, network=net).stable is True
