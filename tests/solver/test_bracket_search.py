"""The deeper lower-bound searches of the brackets (docs/design.md §8.4): prefix search (cost), pattern growth (hinf).

References: the buffer simulated sample by sample (written here, not the library's lifting), brute force over every
admissible prefix of a short horizon closed by the certificate, seeded random sequences (Monte Carlo), python-control's
H-infinity norm of the witness's lifted period.
"""

import itertools

import control
import numpy as np
import pytest

from solver import PlantFamily, design
from solver.brackets import _cycle, _tails, lower_bound, period_system, prefix_search
from solver.lifting import lift_modes
from solver.network import ModeSet

F = [[[1.1, 0.3], [0.0, 0.95]], [[1.05, 0.2], [0.1, 1.0]]]
G = [[[0.2], [1.0]], [[0.1], [0.8]]]
X0 = np.array([0.3, 2.0])
N = 3


@pytest.fixture(scope="module")
def fam():
    return PlantFamily(F=F, G=G)


@pytest.fixture(scope="module")
def res(fam):
    out = design(fam, N, objective="cost", x0=X0)
    assert out.outcome == "stabilized" and out.performance.verified
    return out


def simulate(fam, gains, x0, seq):
    """Cost sum x'x + u'u (Q = I, R = I) of the intervals ``seq`` ((plant, eta) each), the buffer sample by sample."""
    x, cost = np.array(x0, dtype=float), 0.0
    for plant, eta in seq:
        xm = x.copy()
        for t in range(eta):
            u = gains[t] @ xm
            cost += x @ x + u @ u
            x = np.asarray(fam.F[plant]) @ x + np.asarray(fam.G[plant]) @ u
    return cost, x


def _search(fam, res):
    """The prefix search on the designed gains from below (``floor = -inf``: it reports its best sequence even
    where the periodic search's witness is as good), its tails the stable one-mode patterns."""
    lifted = lift_modes(ModeSet.from_family(fam, N), (np.eye(2), np.eye(1)))
    data = lifted.numeric(np.asarray(res.gains, dtype=float))
    tails = _tails(data, [(s,) for s in range(len(data))])
    found = prefix_search(data, tails, res.performance.certificate, np.outer(X0, X0))
    label = [(lm.plants[0], lm.eta) for lm in lifted.lifted]
    return found, [label[s] for s in found.prefix], [label[s] for s in found.tail]


def test_the_prefix_search_witness_is_a_real_sequence_with_its_cost(fam, res):
    """A prefix run once, then a period repeated: simulated sample by sample it costs what the search reports,
    and no more than the certified upper end."""
    found, lead, period = _search(fam, res)
    # (no claim that a prefix wins: on these gains the best "prefix" was the tail itself repeated, (5,) * 9 then (5,),
    # equal to the periodic value to rounding, and gains 1e-7 apart along the x0 optimum's flat face give prefix ())
    cost, x = simulate(fam, res.gains, X0, lead + period * (3000 // len(period)))
    assert np.linalg.norm(x) < 1e-9
    assert cost == pytest.approx(found.value, rel=1e-9)
    assert found.value <= res.performance.upper * (1 + 1e-12)


def test_the_reported_witness_is_a_real_sequence_with_the_reported_cost(fam, res):
    """The bracket's witness (``lead`` intervals once, then a period; ``lead`` is 0 when a periodic pattern
    wins): simulating it reaches the lower end."""
    perf = res.performance
    lead, period = perf.witness[:perf.lead], perf.witness[perf.lead:]
    cost, x = simulate(fam, res.gains, X0, lead + period * (3000 // len(period)))
    assert np.linalg.norm(x) < 1e-9
    assert cost == pytest.approx(perf.lower, rel=1e-9)
    assert perf.lower <= perf.upper
    d = perf.to_dict()
    assert d["lead"] == perf.lead and type(perf).from_dict(d).lead == perf.lead


def test_no_admissible_prefix_closed_by_the_certificate_is_below_the_lower_bound(fam, res):
    """Brute force over all 6^5 prefixes of 5 intervals: every sequence costs at most its prefix's cost plus
    x' P x at the prefix's end, so the largest of these bounds the worst case, hence the witnessed lower end."""
    perf = res.performance
    P = perf.certificate
    intervals = [(p, e) for p in range(2) for e in range(1, N + 1)]
    worst = 0.0
    for seq in itertools.product(intervals, repeat=5):
        cost, x = simulate(fam, res.gains, X0, seq)
        worst = max(worst, cost + x @ P @ x)
    assert perf.lower <= worst * (1 + 1e-12)
    # the quadratic bound is the depth-0 one; the reported upper end is the tree's, proved deeper (below this)
    assert perf.upper <= worst * (1 + 1e-12) <= perf.certificate_upper * (1 + 2e-12)


def test_random_sequences_stay_below_the_upper_bound(fam, res):
    rng = np.random.default_rng(5)
    perf = res.performance
    for _ in range(200):
        seq = [(int(rng.integers(2)), int(rng.integers(1, N + 1))) for _ in range(300)]
        cost, _ = simulate(fam, res.gains, X0, seq)
        assert cost <= perf.upper


def test_the_search_bound_lies_between_lower_and_upper(fam, res):
    perf = res.performance
    lifted = lift_modes(ModeSet.from_family(fam, N), (np.eye(2), np.eye(1)))
    gains = np.asarray(res.gains, dtype=float)
    again = lower_bound(lifted, gains, "cost", X0, certificate=perf.certificate)
    assert again.value == pytest.approx(perf.lower, rel=1e-9)
    found, _, _ = _search(fam, res)
    assert found.bound is not None
    assert found.value <= found.bound * (1 + 1e-12) and perf.lower <= found.bound * (1 + 1e-12)
    assert found.bound <= perf.certificate_upper * (1 + 1e-12)
    # without tails (only the greedy continuations end in a cycle) the bound still holds
    bare = prefix_search(lifted.numeric(gains), [], perf.certificate, np.outer(X0, X0))
    assert perf.lower <= bare.bound <= perf.certificate_upper * (1 + 1e-12)


def test_one_mode_n_drop_one_is_still_the_riccati_cost():
    import scipy.linalg

    F1 = np.array([[1.2, 0.4], [0.0, 0.7]])
    G1 = np.array([[0.0], [1.0]])
    P = scipy.linalg.solve_discrete_are(F1, G1, np.eye(2), np.eye(1))
    res = design(PlantFamily(F=[F1], G=[G1]), 1, objective="cost")
    perf = res.performance
    assert perf.upper == pytest.approx(np.trace(P), rel=1e-6) and perf.lower == pytest.approx(np.trace(P), rel=1e-6)
    assert set(perf.witness) == {(0, 1)}  # the only loop mode (a lead of it before its period, or the period alone)


def test_cycle_splits_a_sequence_into_prefix_and_period():
    assert _cycle((3, 1, 0, 1, 0, 1, 0, 1)) == ((3,), (1, 0))
    assert _cycle((2, 2, 2, 2)) == ((), (2,))
    assert _cycle((0, 1, 2)) == ((0, 1), (2,))


def test_hinf_grown_witness_value_is_its_periods_norm():
    """The l2-gain lower end is the H-infinity norm of the witness's lifted period (python-control, to its
    bisection's accuracy); the certificate bounds it."""
    fam = PlantFamily(F=F, G=G)
    res = design(fam, N, objective="hinf", disturbance=[np.eye(2)[:, :1]] * 2)
    perf = res.performance
    assert perf.verified and perf.lower <= perf.upper
    lifted = lift_modes(ModeSet.from_family(fam, N), None, [np.eye(2)[:, :1]] * 2)
    data = lifted.numeric(np.asarray(res.gains, dtype=float))
    index = {(lm.plants[0], lm.eta): s for s, lm in enumerate(lifted.lifted)}
    sys = period_system(data, [index[w] for w in perf.witness])
    # zero inputs padded to a square D (same norm): python-control's Hamiltonian test needs p = m here
    pad = sys["D"].shape[0] - sys["D"].shape[1]
    B, D = np.hstack([sys["B"], np.zeros((2, pad))]), np.hstack([sys["D"], np.zeros((sys["D"].shape[0], pad))])
    norm = control.norm(control.ss(sys["Phi"], B, sys["C"], D, True), p="inf")
    assert perf.lower == pytest.approx(norm, rel=1e-6)  # python-control's bisection stops at about 1e-7


def test_pattern_growth_is_deterministic_and_its_values_are_lower_bounds():
    """Grown patterns (longer than their seeds) with coarse sweep values at or below the certified upper end; a
    count budget, not a time, so a second run gives the same patterns."""
    from solver.brackets import grow_patterns, hinf_norm_lower

    fam = PlantFamily(F=F, G=G)
    res = design(fam, N, objective="hinf", disturbance=[np.eye(2)[:, :1]] * 2)
    lifted = lift_modes(ModeSet.from_family(fam, N), None, [np.eye(2)[:, :1]] * 2)
    data = lifted.numeric(np.asarray(res.gains, dtype=float))
    seeds = [(-np.inf, (s,)) for s in range(len(data))]
    found, count = grow_patterns(data, seeds, 1)
    again, _ = grow_patterns(data, seeds, 1)
    assert count > 0 and found == again
    assert all(len(p) > 1 for _, p in found)
    for value, p in found[:5]:
        assert value <= hinf_norm_lower(period_system(data, p)) * (1 + 1e-9)
        assert value <= res.performance.upper * (1 + 1e-9)
