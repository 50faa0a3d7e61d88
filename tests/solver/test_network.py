import numpy as np
import pytest

from solver import InvalidInput, PlantFamily
from solver.network import IntervalData, augmented_matrices, check_gains, closed_loop_matrices

from .paper_data import EQ23_GAINS, augmented_by_hand, interval_matrix_by_stepping


def random_family(rng, n=3, m=2, r=2):
    return PlantFamily(F=rng.normal(size=(r, n, n)), G=rng.normal(size=(r, n, m)))


def test_interval_matrices_match_buffer_logic_stepping():
    rng = np.random.default_rng(0)
    fam = random_family(rng)
    n_drop = 4
    gains = rng.normal(size=(n_drop, 2, 3))
    A = closed_loop_matrices(IntervalData.from_family(fam, n_drop), gains)
    assert A.shape == (2, n_drop, 3, 3)
    for l in range(2):
        for eta in range(1, n_drop + 1):
            np.testing.assert_allclose(
                A[l, eta - 1], interval_matrix_by_stepping(fam.F[l], fam.G[l], gains, eta), rtol=1e-12, atol=1e-12
            )


def test_eq7_two_step_interval_by_hand():
    fam = PlantFamily.paper_example(0.1)
    A = closed_loop_matrices(IntervalData.from_family(fam, 3), EQ23_GAINS)
    F, G = fam.F[0], fam.G[0]
    K1, K2 = EQ23_GAINS[0], EQ23_GAINS[1]
    np.testing.assert_allclose(A[0, 1], F @ F + F @ G @ K1 + G @ K2, rtol=1e-13)


def test_augmented_matrix_layout_and_spectrum():
    rng = np.random.default_rng(1)
    fam = random_family(rng, n=2, m=1, r=3)
    gains = rng.normal(size=(3, 1, 2))
    A = closed_loop_matrices(IntervalData.from_family(fam, 3), gains)
    Phi = augmented_matrices(A)
    for l in range(3):
        for e in range(3):
            np.testing.assert_array_equal(Phi[l, e], augmented_by_hand(A[l, e], 3))
            # Phi is block lower triangular with diagonal (A, 0, 0): same nonzero spectrum
            ev_phi = np.sort_complex(np.linalg.eigvals(Phi[l, e]))
            ev = np.sort_complex(np.concatenate([np.linalg.eigvals(A[l, e]), np.zeros(4)]))
            np.testing.assert_allclose(ev_phi, ev, atol=1e-7)


def test_gain_shape_is_checked():
    with pytest.raises(InvalidInput) as err:
        check_gains(np.zeros((2, 1, 2)), 3, 1, 2)
    assert err.value.field == ("gains",)
    # single-input gains may be given as (n_drop, n)
    assert check_gains(np.zeros((3, 2)), 3, 1, 2).shape == (3, 1, 2)
    with pytest.raises(InvalidInput):
        check_gains([[[np.nan, 0]]] * 3, 3, 1, 2)


@pytest.mark.parametrize("n_drop", [0, -1, 2.5, "3", True, None])
def test_bad_n_drop(n_drop):
    with pytest.raises(InvalidInput) as err:
        IntervalData.from_family(PlantFamily.paper_example(0.1), n_drop)
    assert err.value.field == ("n_drop",)
