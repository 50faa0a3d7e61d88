"""python-control in (PlantFamily.from_statespace) and out (solver.control_interop), against scipy's ZOH."""

import numpy as np
import pytest
import scipy.signal

from solver import InvalidInput, PlantFamily

ct = pytest.importorskip("control")

from solver.control_interop import closed_loop_systems, interval_closed_loop, plant_systems  # noqa: E402

H = 0.1
A_MODES = [np.array([[-4.0, -0.3], [5.0, -J]]) for J in (6.667, 10.0, 20.0)]
B = np.array([[2.0], [0.0]])


def motor_systems(**kw):
    return [ct.ss(A, B, [[0.0, 1.0]], 0.0, states=["i_a", "omega"], inputs=["v_a"], **kw) for A in A_MODES]


def test_continuous_statespace_is_zero_order_hold_like_scipy():
    fam = PlantFamily.from_statespace(motor_systems(), sampling_period=H, units={"omega": "rad/s"})
    for l, A in enumerate(A_MODES):
        F, G, *_ = scipy.signal.cont2discrete((A, B, np.eye(2), np.zeros((2, 1))), H, method="zoh")
        np.testing.assert_allclose(fam.F[l], F, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(fam.G[l], G, rtol=1e-12, atol=1e-14)
    assert fam.state_names == ("i_a", "omega") and fam.input_names == ("v_a",)
    assert fam.sampling_period == H and fam.state_label(1) == "omega (rad/s)" and fam.state_label(0) == "i_a"
    np.testing.assert_array_equal(fam.A[2], A_MODES[2])


def test_discrete_statespace_keeps_its_dt_and_default_names_are_dropped():
    disc = [ct.ss(F, G, np.eye(2), 0, 0.05) for F, G in ((np.diag([0.9, 0.5]), [[1.0], [0.0]]),
                                                         (np.diag([1.1, 0.2]), [[0.0], [1.0]]))]
    fam = PlantFamily.from_statespace(disc)
    assert fam.sampling_period == 0.05 and fam.state_names is None and fam.input_names is None
    np.testing.assert_array_equal(fam.F[1], np.diag([1.1, 0.2]))
    assert PlantFamily.from_statespace(disc, sampling_period=0.05).sampling_period == 0.05
    single = PlantFamily.from_statespace(disc[0])  # one StateSpace is unambiguous: a one-mode family
    assert single.n_modes == 1


@pytest.mark.parametrize("call, field, words", [
    (lambda s: PlantFamily.from_statespace(s), ("sampling_period",), "required"),
    (lambda s: PlantFamily.from_statespace([ct.c2d(x, H) for x in s], sampling_period=0.2), ("systems", 0),
     "disagrees"),
    (lambda s: PlantFamily.from_statespace([s[0], ct.c2d(s[1], H)], sampling_period=H), ("systems", 1),
     "same time domain"),
    (lambda s: PlantFamily.from_statespace([s[0], np.eye(2)], sampling_period=H), ("systems", 1), "StateSpace"),
    (lambda s: PlantFamily.from_statespace([s[0], ct.ss(A_MODES[0], B, np.eye(2), 0, states=["a", "b"])], H),
     ("systems", 1), "names"),
])
def test_bad_statespace_input_names_the_field(call, field, words):
    with pytest.raises(InvalidInput, match=words) as err:
        call(motor_systems())
    assert err.value.field == field


@pytest.mark.parametrize("kwargs, field", [
    ({"F": np.eye(2), "G": [np.ones((2, 1))]}, ("F",)),
    ({"F": [[1.0, 0.0], [0.0, 1.0]], "G": [np.ones((2, 1))]}, ("F",)),
])
def test_single_matrix_gets_one_error_that_says_how_to_wrap_it(kwargs, field):
    with pytest.raises(InvalidInput, match=r"wrap it in a list: F=\[F\]") as err:
        PlantFamily(**kwargs)
    assert err.value.field == field
    with pytest.raises(InvalidInput, match=r"A=\[A\]"):
        PlantFamily.from_continuous(A_MODES[0], [B], H)


def test_dc_motor_names_states_in_the_order_of_eq_18():
    fam = PlantFamily.dc_motor([0.03], H)
    # eq. 18: d(i_a)/dt = -R/L i_a - Kb/L omega + v/L, so the input enters the first state only.
    assert fam.state_names == ("i_a", "omega") and fam.A[0][0, 0] == -4.0 and fam.B[0][1, 0] == 0.0
    assert fam.units == {"i_a": "A", "omega": "rad/s", "v_a": "V"}
    assert [fam.state_label(0), fam.state_label(1), fam.input_label(0)] == ["i_a (A)", "omega (rad/s)", "v_a (V)"]
    with pytest.raises(InvalidInput) as err:
        PlantFamily(F=fam.F, G=fam.G, state_names=["only_one"])
    assert err.value.field == ("state_names",)
    with pytest.raises(InvalidInput) as err:
        PlantFamily(F=fam.F, G=fam.G, state_names=["a", "b"], units={"c": "m"})
    assert err.value.field == ("units", "c")


def test_closed_loops_match_an_independent_simulation():
    fam = PlantFamily.from_statespace(motor_systems(), sampling_period=H)
    rng = np.random.default_rng(3)
    K = rng.normal(scale=0.5, size=(3, 1, 2))
    loops = closed_loop_systems(fam, K)
    assert len(loops) == 3 and loops[0].dt == H and loops[0].state_labels == ["i_a", "omega"]
    assert loops[0].output_labels == ["i_a", "omega", "v_a"]
    for l, sys in enumerate(loops):
        # eta = 1: x(k+1) = (F + G K1) x(k), u = K1 x
        np.testing.assert_allclose(sys.A, fam.F[l] + fam.G[l] @ K[0], atol=1e-14)
        resp = ct.initial_response(sys, T=np.arange(4) * H, X0=[1.0, -1.0])
        x = np.array([1.0, -1.0])
        for k in range(4):
            np.testing.assert_allclose(resp.outputs[:2, k], x, atol=1e-12)
            np.testing.assert_allclose(resp.outputs[2, k], K[0] @ x, atol=1e-12)
            x = fam.F[l] @ x + fam.G[l] @ (K[0] @ x)
    # eta = 3: two losses, the buffer plays K1 x, K2 x, K3 x from the same x(i_m)
    A3 = interval_closed_loop(fam, K, 3)
    for l in range(3):
        x0 = np.array([0.3, 2.0])
        x = x0
        for q in range(3):
            x = fam.F[l] @ x + fam.G[l] @ (K[q] @ x0)
        np.testing.assert_allclose(A3[l] @ x0, x, atol=1e-12)
    sys3 = closed_loop_systems(fam, K, eta=3)[1]
    assert sys3.dt == pytest.approx(3 * H) and sys3.ninputs == 0
    with pytest.raises(InvalidInput) as err:
        interval_closed_loop(fam, K, 4)
    assert err.value.field == ("eta",)


def test_plant_systems_round_trip():
    fam = PlantFamily.dc_motor([0.03, 0.05], H)
    systems = plant_systems(fam)
    assert [s.name for s in systems] == ["mode 0", "mode 1"] and systems[0].input_labels == ["v_a"]
    back = PlantFamily.from_statespace(systems)
    np.testing.assert_array_equal(back.F, fam.F)
    np.testing.assert_array_equal(back.G, fam.G)
    assert back.state_names == fam.state_names and back.sampling_period == H
