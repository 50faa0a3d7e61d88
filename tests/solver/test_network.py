import numpy as np
import pytest

from solver import InvalidInput, PlantFamily
from solver.network import ModeSet, augmented_matrices, check_gains

from .paper_data import EQ23_GAINS, augmented_by_hand, interval_matrix_by_stepping


def random_family(rng, n=3, m=2, r=2):
    return PlantFamily(F=rng.normal(size=(r, n, n)), G=rng.normal(size=(r, n, m)))


def test_interval_matrices_match_buffer_logic_stepping():
    rng = np.random.default_rng(0)
    fam = random_family(rng)
    n_drop = 4
    gains = rng.normal(size=(n_drop, 2, 3))
    A = ModeSet.from_family(fam, n_drop).closed_loops(gains).reshape(2, n_drop, 3, 3)
    for l in range(2):
        for eta in range(1, n_drop + 1):
            np.testing.assert_allclose(
                A[l, eta - 1], interval_matrix_by_stepping(fam.F[l], fam.G[l], gains, eta), rtol=1e-12, atol=1e-12
            )


def test_eq7_two_step_interval_by_hand():
    fam = PlantFamily.paper_example(0.1)
    A = ModeSet.from_family(fam, 3).closed_loops(EQ23_GAINS).reshape(3, 3, 2, 2)
    F, G = fam.F[0], fam.G[0]
    K1, K2 = EQ23_GAINS[0], EQ23_GAINS[1]
    np.testing.assert_allclose(A[0, 1], F @ F + F @ G @ K1 + G @ K2, rtol=1e-13)


def test_augmented_matrix_layout_and_spectrum():
    rng = np.random.default_rng(1)
    fam = random_family(rng, n=2, m=1, r=3)
    gains = rng.normal(size=(3, 1, 2))
    A = ModeSet.from_family(fam, 3).closed_loops(gains).reshape(3, 3, 2, 2)
    Phi = augmented_matrices(A, 3)
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
        ModeSet.from_family(PlantFamily.paper_example(0.1), n_drop)
    assert err.value.field == ("n_drop",)


def test_per_sample_modes_match_stepping_with_jumps():
    rng = np.random.default_rng(4)
    fam = random_family(rng, n=2, m=1, r=2)
    gains = rng.normal(size=(3, 1, 2))
    modes = ModeSet.from_family(fam, 3, plant_switching="per_sample")
    assert modes.n_modes == 2 + 4 + 8
    A = modes.closed_loops(gains)
    for s, seq in enumerate(modes.plants):
        # step the buffer with the plant of each sample
        cols = []
        for j in range(2):
            x0 = np.eye(2)[:, j]
            x = x0.copy()
            for q, l in enumerate(seq, start=1):
                x = fam.F[l] @ x + fam.G[l] @ (gains[q - 1] @ x0)
            cols.append(x)
        np.testing.assert_allclose(A[s], np.column_stack(cols), rtol=1e-12, atol=1e-12)


def test_per_sample_mode_count_is_guarded():
    fam = PlantFamily.paper_example(0.1)
    with pytest.raises(InvalidInput) as err:
        ModeSet.from_family(fam, 8, plant_switching="per_sample", max_modes=1000)
    assert err.value.field == ("n_drop",) and "3^eta" not in str(err.value) and "limit" in str(err.value)


@pytest.mark.parametrize("scheme", ["hold", "zero"])
def test_baseline_schemes_restrict_the_gains(scheme):
    rng = np.random.default_rng(5)
    fam = random_family(rng, n=2, m=1, r=2)
    modes = ModeSet.from_family(fam, 3, scheme=scheme)
    theta = rng.normal(size=(1, 1, 2))
    K = modes.expand(theta)
    if scheme == "hold":
        np.testing.assert_array_equal(K, np.repeat(theta, 3, axis=0))
    else:
        np.testing.assert_array_equal(K[1:], 0)
        np.testing.assert_array_equal(K[0], theta[0])
    coef, _ = modes.scheme_coef()
    np.testing.assert_allclose(modes.free + np.einsum("sjab,jbc->sac", coef, theta), modes.closed_loops(K),
                               rtol=1e-12, atol=1e-12)
