"""Beyond the paper: switched design, decay rates, JSR bounds, per-sample jumps, baselines, margins."""

import numpy as np
import pytest

from solver import InvalidInput, PlantFamily, analyze, design, simulate
from solver.margins import design_grid, max_n_drop, max_sampling_period

from .paper_data import EQ23_GAINS, interval_matrix_by_stepping

PAPER = PlantFamily.paper_example(0.1)


def unstable_family(seed):
    """Seeded 2-state, 3-mode, single-input family with every mode's spectral radius in [1.0, 1.1]."""
    rng = np.random.default_rng(seed)
    F = rng.normal(size=(3, 2, 2))
    F = F / np.max(np.abs(np.linalg.eigvals(F)), axis=1)[:, None, None] * rng.uniform(1.0, 1.1, size=(3, 1, 1))
    return PlantFamily(F=F, G=rng.normal(size=(3, 2, 1)))


def interval_maps(fam, gains):
    n_drop = gains.shape[0]
    return [interval_matrix_by_stepping(F, G, gains, eta) for F, G in zip(fam.F, fam.G) for eta in range(1, n_drop + 1)]


def switched_condition_holds(maps, P):
    """Independent check of A_s^T P_t A_s - P_s < 0 for all pairs, P_s > 0."""
    if min(np.linalg.eigvalsh(Ps)[0] for Ps in P) <= 0:
        return False
    return all(np.linalg.eigvalsh(As.T @ Pt @ As - Ps)[-1] < 0 for As, Ps in zip(maps, P) for Pt in P)


def marginal_family(h=0.2):
    # a double integrator and an undamped oscillator: marginally stable open loop
    A = [[[0.0, 1.0], [0.0, 0.0]], [[0.0, 1.0], [-1.0, 0.0]]]
    B = [[[0.0], [1.0]]] * 2
    return PlantFamily.from_continuous(A, B, h)


# ----------------------------------------------------------------------------------- switched
def test_switched_stabilizes_all_lmi_does_and_more():
    counts = {"both": 0, "switched_only": 0, "neither": 0}
    for seed in range(30):
        fam = unstable_family(seed)
        a = design(fam, 3, method="lmi")
        b = design(fam, 3, method="switched")
        if a.outcome == "stabilized":
            assert b.outcome == "stabilized", f"seed {seed}: switched must contain lmi"
            counts["both"] += 1
        elif b.outcome == "stabilized":
            assert a.outcome == "infeasible"
            counts["switched_only"] += 1
        else:
            assert b.outcome == "infeasible"
            counts["neither"] += 1
        if b.outcome == "stabilized":
            assert b.certificate.kind == "switched" and b.certificate.P.shape == (9, 2, 2)
            assert switched_condition_holds(interval_maps(fam, b.gains), b.certificate.P)
            rep = analyze(fam, b.gains, 3)
            assert rep.stable is True
            if a.outcome == "infeasible":
                # no common quadratic certificate exists for these gains either: analyze needed the switched one
                assert rep.certificate.kind == "switched"
    assert counts["both"] >= 1 and counts["switched_only"] >= 1, counts


# --------------------------------------------------------------------------------- decay rate
def test_demanded_decay_rate_is_certified_and_respected():
    res = design(PAPER, 3, method="lmi", decay_rate=0.6)
    assert res.outcome == "stabilized" and res.decay_rate == 0.6
    X = res.certificate.X
    for A, eta in zip(interval_maps(PAPER, res.gains), [1, 2, 3] * 3):
        assert np.linalg.eigvalsh(0.6 ** (2 * eta) * X - A.T @ X @ A)[0] > 0
        assert max(abs(np.linalg.eigvals(A))) ** (1 / eta) <= 0.6
    # a rate below what any gains can do is infeasible, not an error
    assert design(unstable_family(5), 3, method="lmi", decay_rate=0.05).outcome == "infeasible"


@pytest.mark.parametrize("method", ["lmi", "switched"])
def test_best_decay_rate_by_bisection(method):
    res = design(PAPER, 3, method=method, decay_rate="max", rate_tol=1e-3)
    assert res.outcome == "stabilized"
    lam = res.decay_rate
    tried = res.rate_search
    # the probes start at lambda = 1; the rate-following path (lmi's search, switched's start) reports its ends
    assert tried[0]["decay_rate"] == 1.0 or tried[0].get("step") == "path"
    assert tried[0]["outcome"] == "stabilized"
    # the bisection bracket: something within the relative tolerance below lam failed
    failed = [t["decay_rate"] for t in tried if t["outcome"] != "stabilized"]
    assert failed and lam - max(failed) <= 1e-3 * lam
    assert res.rate_bracket["upper"] == lam and lam - res.rate_bracket["lower"] <= 1e-3 * lam
    maps = interval_maps(PAPER, res.gains)
    per_sample_radius = max(max(abs(np.linalg.eigvals(A))) ** (1 / eta) for A, eta in zip(maps, [1, 2, 3] * 3))
    assert per_sample_radius <= lam
    rep = analyze(PAPER, res.gains, 3)
    assert per_sample_radius - 1e-9 <= rep.decay_rate <= lam + 1e-3


def test_simulated_decay_stays_under_the_certified_bound():
    res = design(PAPER, 3, method="lmi", decay_rate=0.5)
    X = res.certificate.X
    worst = 0.0
    for seed in range(40):
        tr = simulate(PAPER, res.gains, 3, x0=[-3, 2], steps=60, seed=seed, loss_model="bernoulli",
                      sensor_loss=0.3, control_loss=0.3)
        v0 = np.sqrt(tr.state[0] @ X @ tr.state[0])
        for k in tr.interval_start:
            x = tr.state[k]
            if np.sqrt(x @ X @ x) > 1e-250:
                worst = max(worst, (np.sqrt(x @ X @ x) / v0) / 0.5**k)
    assert 0 < worst <= 1 + 1e-9


# ---------------------------------------------------------------------------------- JSR bounds
def test_jsr_bounds_bracket_a_known_joint_spectral_radius():
    # {a [[1,1],[0,1]], a [[1,0],[1,1]]} has JSR a * golden ratio, attained by the product of both
    a = 0.55
    fam = PlantFamily(F=[a * np.array([[1.0, 1.0], [0.0, 1.0]]), a * np.array([[1.0, 0.0], [1.0, 1.0]])],
                      G=[np.zeros((2, 1))] * 2)
    rep = analyze(fam, np.zeros((1, 1, 2)), 1, bounds="all")
    jsr = a * (1 + 5**0.5) / 2
    assert rep.jsr_lower_bound == pytest.approx(jsr, rel=1e-9)
    assert jsr - 1e-9 <= rep.jsr_upper_bound <= jsr * 1.05
    assert rep.jsr_upper_bound_switched <= rep.jsr_upper_bound_quadratic + 1e-3
    assert rep.stable is True


def test_switched_bound_beats_quadratic_where_no_common_certificate_exists():
    fam = unstable_family(5)  # stabilized by the switched design only (see above)
    gains = design(fam, 3, method="switched").gains
    rep = analyze(fam, gains, 3, bounds="all")
    assert rep.stable is True and rep.certificate.kind == "switched"
    assert rep.jsr_upper_bound_quadratic is None or rep.jsr_upper_bound_quadratic > 1 - 1e-3
    assert rep.jsr_upper_bound_switched < 1
    assert rep.jsr_lower_bound <= rep.jsr_upper_bound_switched + 1e-9


def test_paper_gains_bounds_are_consistent():
    rep = analyze(PAPER, EQ23_GAINS, 3)
    assert rep.jsr_lower_bound <= rep.jsr_upper_bound < 1
    assert rep.jsr_upper_bound >= rep.max_spectral_radius - 1e-9


# ------------------------------------------------------------------------------- per-sample jumps
def test_per_sample_switching_design_analysis_and_simulation():
    res = design(PAPER, 3, method="lmi", plant_switching="per_sample")
    assert res.outcome == "stabilized" and res.spectral_radii.shape == (3 + 9 + 27,)
    rep = analyze(PAPER, res.gains, 3, plant_switching="per_sample")
    assert rep.stable is True
    # per-sample modes include the per-interval ones, so the per-interval loop is stable too
    assert analyze(PAPER, res.gains, 3).stable is True
    tr = simulate(PAPER, res.gains, 3, x0=[-3, 2], steps=80, seed=1, plant_switching="per_sample")
    assert np.linalg.norm(tr.state[-1]) < 1e-6


def test_per_sample_mode_count_guard():
    with pytest.raises(InvalidInput) as err:
        design(PAPER, 7, plant_switching="per_sample", max_modes=500)
    assert err.value.field == ("n_drop",)


# ------------------------------------------------------------------------------------- baselines
def test_baseline_schemes_have_their_structure_and_smaller_margins():
    fam = marginal_family()
    hold = design(fam, 3, scheme="hold")
    zero = design(fam, 3, scheme="zero")
    assert hold.outcome == zero.outcome == "stabilized"
    np.testing.assert_allclose(hold.gains, np.repeat(hold.gains[:1], 3, axis=0))
    np.testing.assert_array_equal(zero.gains[1:], 0.0)
    assert analyze(fam, hold.gains, 3).stable and analyze(fam, zero.gains, 3).stable
    # hold and zero restrict the predictive gains, so their margins cannot be larger
    margins = {s: max_n_drop(fam, "lmi", n_drop_max=10, scheme=s).margin for s in ("predictive", "hold", "zero")}
    assert margins["predictive"] >= margins["hold"] and margins["predictive"] >= margins["zero"]
    assert margins["hold"] < margins["predictive"]


# --------------------------------------------------------------------------------------- margins
def test_max_n_drop_margin_and_curve():
    fam = marginal_family()
    res = max_n_drop(fam, "lmi", n_drop_max=10, scheme="hold")
    M = res.margin
    assert [p["n_drop"] for p in res.curve] == list(range(1, M + 2))
    assert res.curve[-1]["outcome"] == "infeasible" and all(p["outcome"] == "stabilized" for p in res.curve[:-1])
    assert res.design.n_drop == M and analyze(fam, res.design.gains, M, scheme="hold").stable is True


def test_max_sampling_period_by_bisection():
    fam = marginal_family()
    res = max_sampling_period(fam, 4, "lmi", h_min=0.05, h_max=6.0, tol=0.01, scheme="hold")
    h = res.margin
    assert 0.05 < h < 6.0
    failed_above = [p["sampling_period"] for p in res.curve if p["outcome"] != "stabilized"]
    assert min(failed_above) - h <= 0.01 + 1e-12
    again = design(PlantFamily.from_continuous(fam.A, fam.B, h), 4, scheme="hold", decay_rate=None)  # as margins do
    assert again.outcome == "stabilized"
    np.testing.assert_allclose(res.design.gains, again.gains, rtol=1e-6, atol=1e-9)


def test_design_grid_and_cancellation():
    fam = marginal_family()
    grid = design_grid(fam, [(0.1, 2), (0.5, 3), (1.0, 4)], "lmi")
    assert [(p["sampling_period"], p["n_drop"]) for p in grid.curve] == [(0.1, 2), (0.5, 3), (1.0, 4)]
    assert all(p["outcome"] in ("stabilized", "infeasible") for p in grid.curve)
    calls = []
    stopped = design_grid(fam, [(0.1, 2), (0.5, 3), (1.0, 4)], "lmi", callback=lambda p: calls.append(p) or True)
    assert stopped.stopped and len(stopped.curve) == 1 and calls[0]["step"] == 1
    with pytest.raises(InvalidInput):
        max_sampling_period(PlantFamily(F=[np.eye(2)], G=[np.ones((2, 1))]), 2)
