"""The prefix tree's certified cost bound (docs/design.md §8.4, "Tree bound").

References: exact rational arithmetic on the float64 data (every admissible prefix of a short horizon enumerated,
``fractions.Fraction``), the witnessed lower end, the quadratic certificate's own bound, the Riccati cost
(``scipy.linalg.solve_discrete_are``).
"""

from fractions import Fraction

import numpy as np
import pytest
import scipy.linalg

from solver import PlantFamily, design
from solver.brackets import Performance, _moment, _tails, prefix_search, recheck_tree_bound, tree_bound
from solver.lifting import lift_modes
from solver.network import ModeSet


def _random_family(seed: int, r: int, n: int):
    rng = np.random.default_rng(300 + seed)
    F = rng.normal(size=(r, n, n))
    F = F / np.max(np.abs(np.linalg.eigvals(F)), axis=1)[:, None, None] * rng.uniform(0.8, 1.25, size=(r, 1, 1))
    return PlantFamily(F=F, G=rng.normal(size=(r, n, 1)))


# (seed, plants, states, n_drop): 2 or 3 loop modes (plants x n_drop), short horizons
FAMILIES = [(0, 1, 2, 3), (1, 2, 2, 1), (6, 3, 3, 1), (3, 1, 3, 2)]


def _designed(seed, r, n, N, x0):
    fam = _random_family(seed, r, n)
    res = design(fam, N, objective="cost", x0=x0)
    if res.outcome != "stabilized":
        pytest.skip(f"family {seed}: {res.outcome}")
    lifted = lift_modes(ModeSet.from_family(fam, N), (np.eye(n), np.eye(1)))
    data = lifted.numeric(np.asarray(res.gains, dtype=float))
    return res.performance, data


@pytest.mark.parametrize("with_x0", [False, True], ids=["trace", "x0"])
@pytest.mark.parametrize("case", FAMILIES, ids=lambda c: f"seed{c[0]}-r{c[1]}-n{c[2]}-N{c[3]}")
def test_the_tree_bound_covers_every_prefix_in_exact_arithmetic(case, with_x0):
    """Stopped at depth 4, the search's certified bound is at least the exact largest ``c_4 + <P, Sigma_4>`` over
    all admissible 4-interval prefixes (so, with P's inequality checked exactly, at least every sequence's cost),
    and at least the witnessed lower end; the exact re-check refuses a bound just below that maximum."""
    seed, r, n, N = case
    x0 = np.linspace(1.0, -0.5, n) if with_x0 else None
    perf, data = _designed(seed, r, n, N, x0)
    assert len(data) in (2, 3)
    P = perf.certificate
    M = _moment(n, x0, None)
    found = prefix_search(data, _tails(data, [(s,) for s in range(len(data))]), P, M, max_depth=4)
    ok, worst = recheck_tree_bound(data, P, found.bound, 4, x0=x0)
    assert ok and worst is not None and Fraction(found.bound) >= worst
    assert found.bound >= perf.lower * (1 - 1e-12)
    assert found.bound <= perf.certificate_upper * (1 + 1e-12)
    # the re-check has teeth: the exact maximum minus a hair fails, and so does a P too small for its inequality
    assert not recheck_tree_bound(data, P, float(worst) * (1 - 1e-12), 4, x0=x0)[0]
    assert recheck_tree_bound(data, 0.5 * P, 1e300, 1, x0=x0) == (False, None)
    # the bracket's own (full-depth) bound: between the witness and the quadratic certificate's bound
    assert perf.lower <= perf.upper <= perf.certificate_upper
    value = float(np.trace(P)) if x0 is None else float(x0 @ P @ x0)
    assert perf.certificate_upper == pytest.approx(value, rel=1e-12)


@pytest.mark.parametrize("case", FAMILIES[1:3], ids=lambda c: f"seed{c[0]}-r{c[1]}-n{c[2]}-N{c[3]}")
def test_the_best_first_bound_covers_every_prefix_in_exact_arithmetic(case):
    """Two or three loop modes, S + S^2 + S^3 prefixes valued, so the best-first frontier lies within depth 3 and
    its bound is at least the exact largest ``c_3 + <P, Sigma_3>``; with the witness to close nodes and its full
    budget it lies between the lower end and the quadratic bound."""
    seed, r, n, N = case
    perf, data = _designed(seed, r, n, N, None)
    S = len(data)
    bound, nodes = tree_bound(data, perf.certificate, np.eye(n), -np.inf, budget=S + S**2 + S**3)
    assert nodes == S + S**2 + S**3
    ok, worst = recheck_tree_bound(data, perf.certificate, bound, 3)
    assert ok and Fraction(bound) >= worst
    closed, _ = tree_bound(data, perf.certificate, np.eye(n), perf.lower)
    assert perf.lower <= closed <= perf.certificate_upper * (1 + 1e-12)


@pytest.mark.parametrize("with_x0", [False, True], ids=["trace", "x0"])
def test_one_mode_n_drop_one_is_the_riccati_cost_at_both_ends(with_x0):
    F1 = np.array([[1.2, 0.4], [0.0, 0.7]])
    G1 = np.array([[0.0], [1.0]])
    Q, R = np.diag([2.0, 0.5]), np.array([[3.0]])
    x0 = np.array([1.0, -2.0]) if with_x0 else None
    Pr = scipy.linalg.solve_discrete_are(F1, G1, Q, R)
    optimum = float(np.trace(Pr)) if x0 is None else float(x0 @ Pr @ x0)
    perf = design(PlantFamily(F=[F1], G=[G1]), 1, objective="cost", weights=(Q, R), x0=x0).performance
    assert perf.verified
    assert perf.upper == pytest.approx(optimum, rel=1e-6) and perf.lower == pytest.approx(optimum, rel=1e-6)
    assert perf.upper >= optimum * (1 - 1e-12) and perf.lower <= perf.upper


def test_the_tree_bound_is_strictly_tighter_than_the_quadratic_one():
    """Two masses, n_drop = 3 (6 loop modes): the common quadratic certificate's bound exceeds the worst case; the
    tree closes the bracket.  Independent evidence that the tighter number holds: the same search stopped at depth 3,
    re-checked in exact arithmetic over all 216 prefixes, already proves a bound below the quadratic one."""
    F = [[[1.1, 0.3], [0.0, 0.95]], [[1.05, 0.2], [0.1, 1.0]]]
    G = [[[0.2], [1.0]], [[0.1], [0.8]]]
    fam = PlantFamily(F=F, G=G)
    res = design(fam, 3, objective="cost")
    perf = res.performance
    assert perf.verified and "prefix tree on P" in perf.message
    old_gap = (perf.certificate_upper - perf.lower) / perf.certificate_upper
    assert old_gap > 1e-5
    assert perf.upper < perf.certificate_upper * (1 - 1e-5) and perf.gap < old_gap / 100
    data = lift_modes(ModeSet.from_family(fam, 3), (np.eye(2), np.eye(1))).numeric(np.asarray(res.gains, float))
    found = prefix_search(data, [], perf.certificate, np.eye(2), max_depth=3)
    assert found.depth == 3 and found.bound < perf.certificate_upper
    ok, worst = recheck_tree_bound(data, perf.certificate, found.bound, 3)
    assert ok and worst < Fraction(perf.certificate_upper)
    # both numbers travel with the bracket
    back = Performance.from_dict(perf.to_dict())
    assert back.upper == perf.upper and back.certificate_upper == perf.certificate_upper


def test_the_refusal_of_a_contradiction_still_works(monkeypatch):
    """A witness above the (tree) upper end means something is wrong: the bracket refuses both ends."""
    from solver import brackets

    F = [[[1.1, 0.3], [0.0, 0.95]], [[1.05, 0.2], [0.1, 1.0]]]
    G = [[[0.2], [1.0]], [[0.1], [0.8]]]
    fam = PlantFamily(F=F, G=G)
    res = design(fam, 3, objective="cost")
    lifted = lift_modes(ModeSet.from_family(fam, 3), (np.eye(2), np.eye(1)))
    real = brackets.lower_bound

    def inflated(*args, **kwargs):
        out = real(*args, **kwargs)
        return out._replace(value=out.bound * (1 + 1e-5))

    monkeypatch.setattr(brackets, "lower_bound", inflated)
    # the exact evaluation of the witness corrects a float64 value 1e-5 too high ...
    perf = brackets.bracket(lifted, np.asarray(res.gains, float), "cost", P0=res.performance.certificate)
    assert perf.verified and perf.lower <= perf.upper and "(float64: +1e-05 relative)" in perf.message
    # ... and an exact value above the upper end is refused with it
    monkeypatch.setattr(brackets, "exact_cost_witness", lambda data, found, *a, **k: (found.value, ""))
    perf = brackets.bracket(lifted, np.asarray(res.gains, float), "cost", P0=res.performance.certificate)
    assert perf.upper is None and not perf.verified and "refused" in perf.message


def test_the_exact_recheck_refuses_an_indefinite_p():
    """``P - A' P A >= S`` alone proves nothing when P is not positive semidefinite: A = 2, P = -1, S = 1 satisfy it,
    every sequence diverges, and ``c_1 + <P, Sigma_1> = 1 - 4 = -3`` would pass any bound >= -3."""
    data = [{"A": np.array([[2.0]]), "S": np.array([[1.0]])}]
    assert recheck_tree_bound(data, np.array([[-1.0]]), 0.0, 1) == (False, None)
