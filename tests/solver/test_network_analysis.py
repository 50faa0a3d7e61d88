"""analyze(..., network=net) against brute force over admissible cycles and stepped runs."""

import itertools

import numpy as np
import pytest

from solver import InvalidInput, Network, PlantFamily, analyze

from .paper_data import EQ23_GAINS

# Drop-only design of this plant (solver.design(fam, n_drop=2), rounded): certified for the paper's network.
DELAY_FAMILY = dict(F=[[[0.19, -0.52], [-0.41, -2.44]]], G=[[[1.8], [1.14]]])
DELAY_GAINS = np.array([[[0.2259, 1.6081]], [[-0.1100, -0.4376]]])


def stepped_product(F, G, K, ages, modes):
    """Map xi(0) -> xi(k) of the loop x(t+1) = F_l x(t) + G_l K_{d+1} x(t-d), stepped on unit vectors."""
    N, n = K.shape[0], F.shape[-1]
    cols = []
    for e in np.eye(n * N):
        hist = [e[i * n:(i + 1) * n] for i in range(N)]  # hist[i] = x(t-i)
        for d, l in zip(ages, modes):
            x_next = F[l] @ hist[0] + G[l] @ K[d] @ hist[d]
            hist = [x_next] + hist[:-1]
        cols.append(np.concatenate(hist))
    return np.array(cols).T


def admissible_cycles(net, n_plants, length, per_sample=False):
    """(ages, modes) of every period-`length` admissible pattern; plant modes change only at fresh packets
    (or anywhere with ``per_sample``)."""
    for ages in itertools.product(range(net.n_drop), repeat=length):
        if not net.admissible(list(ages) * (net.nodes + 1)):
            continue
        for modes in itertools.product(range(n_plants), repeat=length):
            ok = per_sample or all(modes[t] == modes[t - 1] or ages[t] <= ages[t - 1] for t in range(length))
            if ok:
                yield ages, modes


def brute_force_radius(fam, K, net, max_length, per_sample=False):
    best = 0.0
    for k in range(1, max_length + 1):
        for ages, modes in admissible_cycles(net, fam.n_modes, k, per_sample):
            M = stepped_product(fam.F, fam.G, K, ages, modes)
            best = max(best, max(abs(np.linalg.eigvals(M))) ** (1.0 / k))
    return best


def test_one_sample_delay_destabilizes_a_drop_only_design():
    fam = PlantFamily(**DELAY_FAMILY)
    assert analyze(fam, DELAY_GAINS, n_drop=2).stable is True
    rep = analyze(fam, DELAY_GAINS, network=Network.delays(1, 2))
    assert rep.stable is False and rep.certificate is None
    cyc = rep.unstable_cycle
    assert Network.delays(1, 2).admissible(cyc["ages"] * 3)
    M = stepped_product(fam.F, fam.G, DELAY_GAINS, cyc["ages"], cyc["modes"])
    assert max(abs(np.linalg.eigvals(M))) > 1.5  # far from 1: float64 eigenvalues decide
    assert rep.jsr_lower_bound >= 1 and rep.to_dict()["unstable_cycle"] == cyc
    assert rep.network == Network.delays(1, 2).to_dict()


@pytest.mark.parametrize("net", [Network.delays(1, 3), Network.delays(2, 3), Network.weakly_hard(2, 5, 3),
                                 Network.delays(1, 3, min_delay=1)])
@pytest.mark.parametrize("scale", [1.0, 2.5])
def test_cycle_bounds_against_brute_force(net, scale):
    fam = PlantFamily.paper_example(0.1)
    K = scale * EQ23_GAINS
    rep = analyze(fam, K, network=net, max_product_length=4)
    brute = brute_force_radius(fam, K, net, 4)
    assert rep.jsr_lower_estimate == pytest.approx(brute, rel=1e-9)
    if rep.jsr_lower_bound is not None:
        assert rep.jsr_lower_bound <= brute * (1 + 1e-9)
    if rep.jsr_upper_bound is not None:
        assert rep.jsr_upper_bound >= brute * (1 - 1e-9)
    if rep.stable is True:
        assert brute < 1
    if rep.stable is False:
        ages, modes = rep.unstable_cycle["ages"], rep.unstable_cycle["modes"]
        assert net.admissible(ages * (net.nodes + 1))
        M = stepped_product(fam.F, fam.G, K, ages, modes)
        assert max(abs(np.linalg.eigvals(M))) >= 1 - 1e-9


def test_per_sample_plant_switching_against_brute_force():
    fam = PlantFamily.paper_example(0.1)
    K = 2.5 * EQ23_GAINS
    net = Network.delays(1, 3)
    rep = analyze(fam, K, network=net, max_product_length=3, plant_switching="per_sample", bounds="none")
    assert rep.jsr_lower_estimate == pytest.approx(brute_force_radius(fam, K, net, 3, per_sample=True), rel=1e-9)
    interval = analyze(fam, K, network=net, max_product_length=3, bounds="none")
    assert rep.jsr_lower_estimate >= interval.jsr_lower_estimate * (1 - 1e-12)  # more switching, no smaller


@pytest.mark.parametrize("net", [Network.delays(2, 3), Network.weakly_hard(2, 5, 3)])
def test_certified_lyapunov_values_decrease_on_random_runs(net):
    fam = PlantFamily.paper_example(0.1)
    rep = analyze(fam, EQ23_GAINS, network=net, bounds="none")
    assert rep.stable is True and rep.certificate.verified
    P = rep.certificate.P
    index = {tuple(s): v for v, s in enumerate(rep.certificate.states)}
    rng = np.random.default_rng(7)
    N, n = net.n_drop, fam.n_states
    for _ in range(20):
        node, plant = int(rng.integers(net.nodes)), int(rng.integers(fam.n_modes))
        hist = [rng.normal(size=n) for _ in range(N)]
        for _ in range(40):
            xi = np.concatenate(hist)
            d = int(net.ages[node])
            x_next = fam.F[plant] @ hist[0] + fam.G[plant] @ EQ23_GAINS[d] @ hist[d]
            nxt = int(rng.choice(net.successors(node)))
            new_plant = int(rng.integers(fam.n_modes)) if net.ages[nxt] <= d else plant
            hist = [x_next] + hist[:-1]
            xi_next = np.concatenate(hist)
            v, w = index[(node, plant)], index[(nxt, new_plant)]
            assert xi_next @ P[w] @ xi_next < xi @ P[v] @ xi
            node, plant = nxt, new_plant


def test_exact_check_near_one():
    # constant age 1: x(t+1) = 0.5 x(t) + k2 x(t-1); k2 = 0.5 puts a root exactly at z = 1
    fam = PlantFamily(F=[[[0.5]]], G=[[[1.0]]])
    rep = analyze(fam, [[[-0.5]], [[0.5]]], network=Network.delays(1, 2))
    assert rep.stable is False and rep.unstable_cycle["ages"] == [1]
    # 2^-40 less: every cycle's radius is below 1, so no instability may be claimed
    rep = analyze(fam, [[[-0.5]], [[0.5 - 2.0**-40]]], network=Network.delays(1, 2))
    assert rep.stable is not False


def test_bounded_drops_network_takes_todays_path():
    fam = PlantFamily.paper_example(0.1)
    today = analyze(fam, EQ23_GAINS, n_drop=3)
    rep = analyze(fam, EQ23_GAINS, network=Network.bounded_drops(3))
    assert rep.stable is True and rep.certificate.kind == today.certificate.kind
    np.testing.assert_array_equal(rep.certificate.P, today.certificate.P)
    assert rep.network == {"kind": "bounded_drops", "n_drop": 3}
    unstable = analyze(fam, 3 * EQ23_GAINS, network="drops:3")
    assert unstable.stable is False
    ages, modes = unstable.unstable_cycle["ages"], unstable.unstable_cycle["modes"]
    M = stepped_product(fam.F, fam.G, 3 * EQ23_GAINS, ages, modes)
    assert max(abs(np.linalg.eigvals(M))) >= 1


def test_network_argument_errors():
    fam = PlantFamily.paper_example(0.1)
    with pytest.raises(InvalidInput) as err:
        analyze(fam, EQ23_GAINS, n_drop=2, network=Network.delays(1, 3))
    assert err.value.field == ("n_drop",)
    with pytest.raises(InvalidInput) as err:
        analyze(fam, EQ23_GAINS, network={"kind": "delays", "max_delay": 5, "n_drop": 3})
    assert err.value.field == ("network", "max_delay")
    with pytest.raises(InvalidInput) as err:
        analyze(fam, EQ23_GAINS)
    assert err.value.field == ("n_drop",)
    with pytest.raises(InvalidInput) as err:
        analyze(fam, EQ23_GAINS, network=Network.delays(1, 3), weights=(np.eye(2), np.eye(1)))
    assert err.value.field == ("weights",)


@pytest.mark.parametrize("rho", [1.0, 0.9])
def test_node_sdp_on_the_ipm_against_clarabel(rho):
    """The node-dependent SDP of analyze(network=) in the IPM's max-t form: its margin's sign agrees with Clarabel's
    min-trace form (a second solver), and its P passes the float64 re-check exactly when the rate is above the
    CJSR's quadratic bound; under "IPM" and "CLARABEL" the analysis gives the same verdict."""
    from solver.network_analysis import NodeLMI, product_automaton, recheck_node_dependent
    from solver.networks import loop_matrices
    from solver.ipm.network_blocks import solve_node

    fam = PlantFamily(**DELAY_FAMILY)
    # the drop-only design is certified on bounded_drops(2); its delays(1, 2) age-1 cycle has radius 2.24
    for net in (Network.bounded_drops(2), Network.delays(1, 2)):
        prod = product_automaton(net, fam.n_modes, "per_interval")
        A = loop_matrices(fam, DELAY_GAINS, net)[prod.modes, prod.ages]
        t, P, status = solve_node(A, prod.succ, rho)
        lmi = NodeLMI(A, prod)
        P2 = lmi.solve(rho, "CLARABEL")
        other = P2 is not None and recheck_node_dependent(P2, A, prod, rho).verified
        assert status == "optimal"
        assert (t > 1e-7) == other, (net.describe(), rho, t, other)
        assert recheck_node_dependent(P, A, prod, rho).verified == (t > 1e-7)
        if rho == 1.0:
            verdicts = {s: analyze(fam, DELAY_GAINS, network=net, solver=s, bounds="none").stable
                        for s in ("IPM", "CLARABEL", "AUTO")}
            assert len(set(verdicts.values())) == 1, verdicts
