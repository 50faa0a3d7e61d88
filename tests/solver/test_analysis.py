import numpy as np
import pytest

from solver import PlantFamily, analyze

from .paper_data import EQ23_GAINS, EQ24_GAINS, interval_matrix_by_stepping, theorem1_holds


@pytest.mark.parametrize("h, gains", [(0.1, EQ23_GAINS), (0.2, EQ24_GAINS)])
def test_paper_gains_are_certified_stable(h, gains):
    fam = PlantFamily.paper_example(h)
    rep = analyze(fam, gains, n_drop=3)
    assert rep.stable is True
    assert rep.certificate.verified and rep.margin > 1e-3
    ok, worst = theorem1_holds(fam.F, fam.G, gains, rep.certificate.P)
    assert ok and worst > 0
    # spectral radii against matrices built by stepping the buffer logic
    for l in range(3):
        for eta in (1, 2, 3):
            A = interval_matrix_by_stepping(fam.F[l], fam.G[l], gains, eta)
            assert rep.spectral_radii[l, eta - 1] == pytest.approx(max(abs(np.linalg.eigvals(A))), rel=1e-10)
    assert rep.jsr_lower_bound < 1


def test_unstable_mode_is_reported_with_its_sequence():
    fam = PlantFamily.paper_example(0.1)
    gains = 3 * EQ23_GAINS
    rep = analyze(fam, gains, n_drop=3)
    assert rep.stable is False and rep.certificate is None
    (worst,) = rep.worst_sequence
    l, eta = worst["plant"], worst["eta"]
    A = interval_matrix_by_stepping(fam.F[l], fam.G[l], gains, eta)
    assert max(abs(np.linalg.eigvals(A))) >= 1
    assert rep.max_spectral_radius == pytest.approx(max(abs(np.linalg.eigvals(A))))


def test_destabilizing_product_of_stable_modes():
    # both modes are nilpotent (spectral radius 0), their product has spectral radius 4
    F = [[[0.0, 2.0], [0.0, 0.0]], [[0.0, 0.0], [2.0, 0.0]]]
    fam = PlantFamily(F=F, G=[[[0.0], [0.0]]] * 2)
    rep = analyze(fam, np.zeros((1, 1, 2)), n_drop=1)
    assert rep.max_spectral_radius == 0.0
    assert rep.stable is False
    assert len(rep.worst_sequence) == 2 and {w["plant"] for w in rep.worst_sequence} == {0, 1}
    assert rep.jsr_lower_bound == pytest.approx(2.0)


def test_unknown_when_neither_certificate_nor_short_counterexample():
    # joint spectral radius 0.65 * golden ratio = 1.05 > 1, attained by the product of both modes:
    # no quadratic certificate exists, and single modes (radius 0.65) show nothing
    a = 0.65
    F = [a * np.array([[1.0, 1.0], [0.0, 1.0]]), a * np.array([[1.0, 0.0], [1.0, 1.0]])]
    fam = PlantFamily(F=F, G=[np.zeros((2, 1))] * 2)
    rep = analyze(fam, np.zeros((1, 1, 2)), n_drop=1, max_product_length=1)
    assert rep.stable is None and rep.certificate is None
    rep2 = analyze(fam, np.zeros((1, 1, 2)), n_drop=1, max_product_length=2)
    assert rep2.stable is False
    assert rep2.jsr_lower_bound == pytest.approx(a * (1 + 5**0.5) / 2, rel=1e-9)


def test_certificate_margin_shrinks_towards_the_stability_boundary():
    B1 = np.array([[1.0, 1.0], [0.0, 1.0]])
    B2 = np.array([[1.0, 0.0], [1.0, 1.0]])
    margins = []
    for a in (0.5, 0.58, 0.6):
        fam = PlantFamily(F=[a * B1, a * B2], G=[np.zeros((2, 1))] * 2)
        rep = analyze(fam, np.zeros((1, 1, 2)), n_drop=1)
        assert rep.stable is True
        margins.append(rep.margin)
    assert margins[0] > margins[1] > margins[2] > 0


def test_a_proven_short_product_is_kept_when_a_longer_float_estimate_outranks_it():
    # Two modes made exactly similar by T = [[1, 0], [2^20, 1]]: mode 0 has spectral radius exactly
    # 1.0078125 (the eigenvalues of the triangular M), but float64 products of length 4 lose ~2^40 to
    # cancellation and estimate a larger radius that exact arithmetic does not confirm.
    from fractions import Fraction

    T = np.array([[1.0, 0.0], [2.0**20, 1.0]])
    Ti = np.array([[1.0, 0.0], [-(2.0**20), 1.0]])
    M = np.array([[1.0078125, 0.5], [0.0, 0.25]])
    D = np.array([[0.5, 0.0], [0.5, 0.25]])
    A0, A1 = T @ M @ Ti, T @ D @ Ti
    # independent: A0's characteristic polynomial in exact rationals has the root 1.0078125
    q = [[Fraction(float(x)) for x in row] for row in A0]
    z = Fraction(1.0078125)
    assert (q[0][0] - z) * (q[1][1] - z) - q[0][1] * q[1][0] == 0
    fam = PlantFamily(F=[A0, A1], G=[np.array([[0.0], [1.0]])] * 2)
    for length in (1, 2, 4):
        rep = analyze(fam, np.zeros((1, 1, 2)), n_drop=1, max_product_length=length, bounds="none")
        assert rep.stable is False, length
        assert 1.0 <= rep.jsr_lower_bound <= 1.0078125
        assert rep.worst_sequence == [{"plant": 0, "eta": 1}]
    assert rep.jsr_lower_estimate > 1.1  # the long product's float estimate, reported as an estimate only
@pytest.mark.parametrize("scale,length", [(1e100, 4), (1e60, 6), (1.5e308, 1)])
def test_gains_whose_products_overflow_float64_are_an_input_error_naming_gains(scale, length):
    """Finite gains so large that the products of max_product_length closed loops overflow float64 (issue 20:
    a LinAlgError, 500 over HTTP): InvalidInput on ("gains",), before any product is formed."""
    from solver import InvalidInput

    fam = PlantFamily.paper_example(0.1)
    K = np.zeros((3, 1, 2))
    K[0, 0, 0] = scale
    with pytest.raises(InvalidInput) as err:
        analyze(fam, K, n_drop=3, max_product_length=length)
    assert err.value.field == ("gains",) and "too large" in str(err.value)


def test_large_gains_whose_products_stay_finite_are_analyzed():
    """Just under the overflow check (products of length 2 of norm-1e60 loops stay finite): a verdict, proven."""
    fam = PlantFamily.paper_example(0.1)
    K = np.zeros((3, 1, 2))
    K[0, 0, 0] = 1e60
    rep = analyze(fam, K, n_drop=3, max_product_length=2, bounds="none")
    assert rep.stable is False  # a spectral radius of about 1e59: unstable, proven exactly
