import numpy as np
import pytest
import scipy.signal

from solver import InvalidInput, PlantFamily

from .paper_data import EQ20_F, EQ20_G, EQ21_EIG


def test_zoh_reproduces_eq20_to_four_decimals():
    fam = PlantFamily.paper_example(sampling_period=0.1)
    assert fam.n_modes == 3 and fam.n_states == 2 and fam.n_inputs == 1
    np.testing.assert_allclose(fam.F, EQ20_F, atol=0.5e-4 + 1e-12)
    np.testing.assert_allclose(fam.G, EQ20_G, atol=0.5e-4 + 1e-12)


def test_zoh_matches_scipy_cont2discrete():
    fam = PlantFamily.paper_example(sampling_period=0.2)
    for A, B, F, G in zip(fam.A, fam.B, fam.F, fam.G):
        Fd, Gd, *_ = scipy.signal.cont2discrete((A, B, np.eye(2), np.zeros((2, 1))), 0.2, method="zoh")
        np.testing.assert_allclose(F, Fd, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(G, Gd, rtol=1e-12, atol=1e-14)


def test_eigenvalues_of_eq21():
    fam = PlantFamily.paper_example(sampling_period=0.1)
    for l, (F, printed_F) in enumerate(zip(fam.F, EQ20_F)):
        ours = np.sort(np.linalg.eigvals(F).real)[::-1]
        # against the eigenvalues of the printed eq. 20 matrices (independent of our ZOH)
        np.testing.assert_allclose(ours, np.sort(np.linalg.eigvals(printed_F).real)[::-1], atol=2e-4)
        slow, fast = EQ21_EIG[l]
        assert abs(ours[1] - fast) < 0.5e-4 + 1e-9
        if l == 1:
            # eq. 21 prints 0.671: a typo, eq. 20's own F_2 has 0.6701
            assert abs(ours[0] - 0.6701) < 0.5e-4 and abs(ours[0] - slow) < 1e-3
        else:
            assert abs(ours[0] - slow) < 0.5 * 10 ** -(len(str(slow)) - 2) + 1e-9


def test_dc_motor_from_table_one_matches_hand_derivation():
    fam = PlantFamily.dc_motor(inertias=[0.03, 0.02, 0.01], sampling_period=0.1)
    # A = [[-R/L, -Kb/L], [Km/J, -B/J]] with R=2, L=0.5, Kb=Km=0.15, B=0.2
    np.testing.assert_allclose(fam.A[0], [[-4.0, -0.3], [5.0, -0.2 / 0.03]])
    np.testing.assert_allclose(fam.A[2], [[-4.0, -0.3], [15.0, -20.0]])
    np.testing.assert_allclose(fam.B[1], [[2.0], [0.0]])
    # Table I does not give eq. 19: the off-diagonal entries differ by a factor of 10
    paper = PlantFamily.paper_example(0.1)
    assert not np.allclose(fam.A[0], paper.A[0])


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(F=[[[1, 2, 3], [4, 5, 6]]], G=[[[1], [1]]]), ("F", 0)),
        (dict(F=[np.eye(2), np.eye(3)], G=[np.ones((2, 1)), np.ones((3, 1))]), ("F", 1)),
        (dict(F=[np.eye(2), np.eye(2)], G=[np.ones((2, 1)), np.ones((2, 2))]), ("G", 1)),
        (dict(F=[np.eye(2)], G=[np.ones((3, 1))]), ("G", 0)),
        (dict(F=[[[np.nan, 0], [0, 1]]], G=[[[1], [0]]]), ("F", 0)),
        (dict(F=[[[np.inf, 0], [0, 1]]], G=[[[1], [0]]]), ("F", 0)),
        (dict(F=[[["a", 0], [0, 1]]], G=[[[1], [0]]]), ("F", 0)),
        (dict(F=[], G=[]), ("F",)),
        (dict(F=[np.eye(2)], G=[np.ones((2, 1)), np.ones((2, 1))]), ("G",)),
        (dict(F=[np.eye(2)], G=[np.ones((2, 1))], sampling_period=-0.1), ("sampling_period",)),
    ],
)
def test_invalid_families_name_the_field(kwargs, field):
    with pytest.raises(InvalidInput) as err:
        PlantFamily(**kwargs)
    assert err.value.field == field


@pytest.mark.parametrize("h", [0.0, -1.0, float("nan"), float("inf"), "x"])
def test_from_continuous_rejects_bad_sampling_period(h):
    with pytest.raises(InvalidInput) as err:
        PlantFamily.from_continuous([np.eye(2)], [np.ones((2, 1))], h)
    assert err.value.field == ("sampling_period",)


def test_dc_motor_rejects_non_positive_inertia():
    with pytest.raises(InvalidInput) as err:
        PlantFamily.dc_motor(inertias=[0.03, 0.0], sampling_period=0.1)
    assert err.value.field == ("inertias", 1)
