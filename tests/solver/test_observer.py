"""Output feedback (docs/design.md, "Output feedback"): observer design, joint certificate, simulation.

Independent references: the LQG optimum from the Riccati recursions iterated to convergence (not the
library's solve_discrete_are calls), Sinopoli et al.'s critical arrival probabilities in closed form, the
joint interval maps rebuilt here by stepping the loop's own equations (plant, observer, buffer) sample by
sample, exact rational arithmetic for the obstruction, and seeded runs over random loss patterns.
"""

from __future__ import annotations

import itertools
from fractions import Fraction

import numpy as np
import pytest

from solver import InvalidInput, PlantFamily, analyze, design, simulate
from solver.observer import (critical_arrival, design_observer, lqg_cost, observer_obstruction,
                             unstable_error_cycle)


def motor(C=((0.0, 1.0),), modes=3):
    base = PlantFamily.paper_example()
    return PlantFamily(F=base.F[:modes], G=base.G[:modes], C=C, sampling_period=0.1)


def riccati_by_iteration(F, G, Q, R, steps=20000):
    """Control Riccati solution by value iteration (independent of scipy's solver)."""
    S = Q.copy()
    for _ in range(steps):
        K = np.linalg.solve(R + G.T @ S @ G, G.T @ S @ F)
        S_next = Q + F.T @ S @ F - F.T @ S @ G @ K
        if np.max(np.abs(S_next - S)) <= 1e-15 * max(1.0, np.max(np.abs(S))):
            return S_next
        S = S_next
    return S


def test_lqg_without_losses_reproduces_riccati_and_kalman():
    fam = motor(modes=1)
    Q, R = np.diag([1.0, 2.0]), np.eye(1)
    W, V = np.diag([0.1, 0.2]), 0.05 * np.eye(1)
    res = design(fam, 1, feedback="output", sensor_n_drop=1, objective="cost", weights=(Q, R), noise=(W, V))
    assert res.outcome == "stabilized" and res.joint_certificate is not None
    F, G, C = fam.F[0], fam.G[0], fam.C[0]
    S = riccati_by_iteration(F, G, Q, R)
    K_opt = -np.linalg.solve(R + G.T @ S @ G, G.T @ S @ F)  # u = K x
    P = riccati_by_iteration(F.T, C.T, W, V)  # predicted error covariance (dual recursion)
    L_opt = P @ C.T @ np.linalg.inv(C @ P @ C.T + V)
    assert np.allclose(res.observer_gains[0], L_opt, rtol=1e-8, atol=1e-12)
    assert np.allclose(res.gains[0], K_opt, rtol=1e-8, atol=1e-12)  # Riccati refinement: the LQR gain itself
    # The LQG optimum: tr(S W) + tr(Sigma K'(R + G'SG)K), Sigma the filtered error covariance.
    Sigma = P - L_opt @ C @ P
    J_opt = np.trace(S @ W) + np.trace(Sigma @ K_opt.T @ (R + G.T @ S @ G) @ K_opt)
    J = lqg_cost(fam, res.gains, res.observer_gains, (Q, R), (W, V))
    assert J == pytest.approx(J_opt, rel=1e-8)
    # The cost of the exact LQG pair, from the same Lyapunov route, is the closed form too.
    assert lqg_cost(fam, K_opt[None], L_opt, (Q, R), (W, V)) == pytest.approx(J_opt, rel=1e-10)


@pytest.mark.parametrize("a", [1.2, 1.5, 3.0])
def test_critical_arrival_scalar_matches_sinopoli(a):
    fam = PlantFamily(F=[[[a]]], G=[[[1.0]]], C=[[2.0]])
    # Deadbeat at every arrival (L = 1/c) attains Sinopoli et al.'s bound lambda_c = 1 - 1/a^2.
    assert critical_arrival(fam, [[0.5]]) == pytest.approx(1.0 - 1.0 / a**2, abs=1e-8)


def test_critical_arrival_invertible_C_matches_sinopoli():
    F = np.array([[1.3, 0.4], [0.0, 0.5]])
    C = np.array([[1.0, 1.0], [0.0, 2.0]])
    fam = PlantFamily(F=[F], G=[np.eye(2)], C=C)
    lam_max = np.max(np.abs(np.linalg.eigvals(F)))
    assert critical_arrival(fam, np.linalg.inv(C)) == pytest.approx(1.0 - 1.0 / lam_max**2, abs=1e-8)


def cyclic(a=1.2):
    """F^3 = a I exactly (in binary): with C = e1', the pattern (lose 2, receive 1) hides e2, e3 from every L."""
    F = [[0.0, 0.0, a], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    return PlantFamily(F=[F], G=[[[1.0], [0.0], [0.0]]], C=[[1.0, 0.0, 0.0]])


def test_no_observer_proof_while_full_state_is_certified():
    fam = cyclic()
    state = design(fam, 3)
    assert state.outcome == "stabilized"
    res = design(fam, 3, feedback="output", sensor_n_drop=3)
    assert res.outcome == "infeasible" and res.observer.outcome == "no_observer"
    ob = res.observer.obstruction
    # Independent exact check: F^3 maps the basis into its span with eigenvalue >= 1, and C kills it.
    Fq = [[Fraction(v) for v in row] for row in fam.F[0]]
    F3 = [[sum(Fq[i][k] * Fq[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    F3 = [[sum(F3[i][k] * Fq[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    for b in ob.basis.T:
        bq = [Fraction(float(v)) for v in b]
        assert sum(Fraction(float(c)) * v for c, v in zip(fam.C[0][0], bq)) == 0
        img = [sum(F3[i][j] * bq[j] for j in range(3)) for i in range(3)]
        assert all(img[i] == Fraction(1.2) * bq[i] for i in range(3))
    assert abs(ob.eigenvalue) >= 1
    # Every observer gain fails on that pattern: try random L, the error's periodic map keeps radius >= 1.2.
    rng = np.random.default_rng(0)
    F = fam.F[0]
    for _ in range(50):
        L = rng.normal(size=(3, 1)) * 3
        E = (np.eye(3) - L @ fam.C[0]) @ F @ F @ F
        assert np.max(np.abs(np.linalg.eigvals(E))) >= 1.2 - 1e-9


def test_both_certified_with_fewer_sensor_losses():
    fam = cyclic()
    res = design(fam, 3, feedback="output", sensor_n_drop=1)
    assert res.outcome == "stabilized", res.message
    check_joint_independently(fam, res.gains, 3, res.observer_gains, 1, res.joint_certificate)
    # With one lost measurement allowed there is no proof either way: the words stay honest.
    assert observer_obstruction(fam, 2) is None
    res = design(fam, 3, feedback="output", sensor_n_drop=2)
    assert res.outcome == "not_certified" and "not a proof" in res.message


def loop_step(fam, K, L, x, xh, buf, q, plant, got_y, got_u):
    """One sample of the loop's own equations (plant, observer, buffer): the reference for the joint maps."""
    C = fam.C[plant]
    if got_y:
        xh = xh + L[plant] @ (C @ x - C @ xh)
    if got_u:
        buf, q = K @ xh, 1
    else:
        q += 1
    u = buf[q - 1]
    return fam.F[plant] @ x + fam.G[plant] @ u, fam.F[plant] @ xh + fam.G[plant] @ u, buf, q


def check_joint_independently(fam, K, n_drop, L, M, cert):
    """V = x'Px + e'Q_sigma e (e = x - xh after the update) decreases over every interval and pattern."""
    n, r = fam.n_states, fam.n_modes
    P, Q = cert.P, cert.Q
    checked = 0
    for plant, l_next, eta, sigma in itertools.product(range(r), range(r), range(1, n_drop + 1), range(M)):
        for bits in itertools.product((True, False), repeat=eta):
            lost, ok = sigma, True
            for b in bits:
                lost = 0 if b else lost + 1
                ok &= lost <= M - 1
            if not ok:
                continue
            cols = []
            for j in range(2 * n):
                z = np.zeros(2 * n)
                z[j] = 1.0
                x, e = z[:n], z[n:]
                xh = x - e  # the estimate after the update at the interval's first sample
                buf, q = None, 0
                # sample 0 of the interval delivers the packet built from xh(i|i) (no new update)
                x1, xh1, buf, q = loop_step(fam, K, L, x, xh, buf, q, plant, False, True)
                for t in range(1, eta + 1):
                    mode_t = plant if t < eta else l_next
                    got = bits[t - 1]
                    if t < eta:
                        x1, xh1, buf, q = loop_step(fam, K, L, x1, xh1, buf, q, mode_t, got, False)
                    elif got:  # the next interval's first measurement update
                        C = fam.C[mode_t]
                        xh1 = xh1 + L[mode_t] @ (C @ x1 - C @ xh1)
                cols.append(np.concatenate([x1, x1 - xh1]))
            J = np.array(cols).T
            D_from = np.block([[P, np.zeros((n, n))], [np.zeros((n, n)), Q[sigma]]])
            D_to = np.block([[P, np.zeros((n, n))], [np.zeros((n, n)), Q[lost]]])
            assert np.linalg.eigvalsh(J.T @ D_to @ J - D_from)[-1] < 0
            checked += 1
    assert checked == cert.blocks


def test_paper_motor_measuring_speed():
    fam = motor()
    res = design(fam, 3, feedback="output", sensor_n_drop=3)
    assert res.outcome == "stabilized"
    assert res.observer_gains.shape == (3, 2, 1)
    check_joint_independently(fam, res.gains, 3, res.observer_gains, 3, res.joint_certificate)
    rep = analyze(fam, res.gains, 3, observer_gains=res.observer_gains, sensor_n_drop=3)
    assert rep.stable is True and rep.output.certificate is not None
    d = res.to_dict()
    assert d["feedback"] == "output" and len(d["observer_gains"]) == 3
    # 300 random loss patterns on both links (at most 2 in a row on each): every run converges.
    for seed in range(300):
        tr = simulate(fam, res.gains, 3, x0=[1.0, -2.0], steps=120, seed=seed, observer_gains=res.observer_gains,
                      sensor_n_drop=3, sensor_loss=0.5, control_loss=0.5, xh0=[0.0, 0.0])
        assert np.linalg.norm(tr.state[-1]) < 1e-6 * np.linalg.norm(tr.state[0])
        assert np.linalg.norm(tr.state[-1] - tr.estimate[-1]) < 1e-6
        runs = np.diff(np.flatnonzero(np.concatenate([[True], tr.sensor_arrived, [True]]))) - 1
        assert runs.max() <= 2


def test_simulation_matches_the_loop_equations():
    fam = motor()
    res = design(fam, 3, feedback="output", sensor_n_drop=3)
    tr = simulate(fam, res.gains, 3, x0=[0.3, 1.0], steps=60, seed=7, observer_gains=res.observer_gains,
                  sensor_n_drop=3, sensor_loss=0.4, control_loss=0.4, plant_switching="per_sample")
    x, xh, buf, q = tr.state[0], np.zeros(2), None, 0
    for k in range(60):
        x, xh, buf, q = loop_step(fam, res.gains, res.observer_gains, x, xh, buf, q, int(tr.mode[k]),
                                  bool(tr.sensor_arrived[k]), bool(tr.control_arrived[k]))
        assert np.allclose(x, tr.state[k + 1], rtol=1e-12, atol=1e-14)


def test_bad_observer_is_proven_unstable():
    fam = motor(modes=1)
    res = design(fam, 2)
    L = np.zeros((1, 2, 1))  # no correction: the open-loop error of an unstable motor mode diverges?
    rho = np.max(np.abs(np.linalg.eigvals(fam.F[0])))
    rep = analyze(fam, res.gains, 2, observer_gains=L, sensor_n_drop=2)
    if rho >= 1:
        assert rep.stable is False and rep.output.error_cycle is not None
    # A gain that overshoots: the measured step (I - L C) F has radius > 1 by itself.
    L_bad = np.array([[[0.0], [5.0]]])
    cycle = unstable_error_cycle(fam, L_bad, 2)
    assert cycle is not None
    E = np.eye(2)
    for got in cycle["arrivals"]:
        step = fam.F[0] if not got else (np.eye(2) - L_bad[0] @ fam.C[0]) @ fam.F[0]
        E = step @ E
    assert np.max(np.abs(np.linalg.eigvals(E))) ** (1 / len(cycle["arrivals"])) == pytest.approx(cycle["rate"])
    rep = analyze(fam, res.gains, 2, observer_gains=L_bad, sensor_n_drop=2)
    assert rep.stable is False


def test_common_observer_and_decay_rate():
    fam = motor()
    obs = design_observer(fam, 2, kind="common", decay_rate=0.95)
    assert obs.outcome == "certified"
    assert np.allclose(obs.gains, obs.gains[:1])


def test_bad_inputs_name_the_field():
    fam = PlantFamily.paper_example()
    with pytest.raises(InvalidInput) as err:
        design(fam, 3, feedback="output")
    assert err.value.field[0] == "C"
    with pytest.raises(InvalidInput) as err:
        design(fam, 3, sensor_n_drop=2)
    assert err.value.field[0] == "sensor_n_drop"
    with pytest.raises(InvalidInput) as err:
        design(motor(), 3, feedback="output", sensor_n_drop=0)
    assert err.value.field[0] == "sensor_n_drop"
    with pytest.raises(InvalidInput) as err:
        PlantFamily(F=fam.F, G=fam.G, C=[[1.0, 0.0, 0.0]])
    assert err.value.field[0] == "C"
    with pytest.raises(InvalidInput) as err:
        design(motor(), 3, feedback="output", noise=(np.eye(2), np.zeros((1, 1))))
    assert err.value.field[0] == "noise"
    with pytest.raises(InvalidInput) as err:
        analyze(motor(), np.zeros((3, 1, 2)), 3, observer_gains=np.zeros((3, 3)))
    assert err.value.field[0] == "observer_gains"
    fam2 = PlantFamily.from_continuous(A=[[[0.0, 1.0], [0.0, -1.0]]], B=[[[0.0], [1.0]]], sampling_period=0.1,
                                       C=[[1.0, 0.0]])
    assert fam2.C.shape == (1, 1, 2) and PlantFamily.from_dict(fam2.to_dict() | {"kind": "discrete"}).C.shape == (1, 1, 2)


def test_mat_export_carries_the_observer(tmp_path):
    import scipy.io

    from solver.matlab import save_mat

    fam = motor()
    res = design(fam, 3, feedback="output", sensor_n_drop=2)
    save_mat(tmp_path / "d.mat", res, fam)
    mat = scipy.io.loadmat(tmp_path / "d.mat")
    assert np.allclose(np.moveaxis(mat["L"], -1, 0), res.observer_gains)
    assert np.allclose(mat["P_joint"], res.joint_certificate.P)
    assert mat["Q_joint"].shape == (2, 2, 2) and mat["C"].shape == (1, 2, 3)


def test_generated_c_observer_matches_simulate(tmp_path):
    import shutil
    import subprocess

    from solver.observer_codegen import export_observer_c

    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler")
    fam = motor()
    res = design(fam, 3, feedback="output", sensor_n_drop=2)
    for name, text in export_observer_c(fam, res).items():
        (tmp_path / name).write_text(text)
    (tmp_path / "main.c").write_text(r'''
#include <stdio.h>
#include "ncs_observer.h"
int main(void) {
    ncs_observer_t obs; unsigned steps, k, mode; int got; double y[NCS_OBS_P], u[NCS_OBS_M]; unsigned i;
    if (scanf("%u", &steps) != 1) return 2;
    ncs_observer_init(&obs, 0);
    for (k = 0; k < steps; ++k) {
        if (scanf("%u %d", &mode, &got) != 2) return 2;
        for (i = 0; i < NCS_OBS_P; ++i) if (scanf("%lf", &y[i]) != 1) return 2;
        for (i = 0; i < NCS_OBS_M; ++i) if (scanf("%lf", &u[i]) != 1) return 2;
        if (ncs_observer_update(&obs, mode, y, got) != 0) return 3;
        for (i = 0; i < NCS_OBS_N; ++i) printf("%.17g ", ncs_observer_estimate(&obs)[i]);
        printf("\n");
        if (ncs_observer_predict(&obs, mode, u) != 0) return 3;
    }
    return 0;
}
''')
    exe = tmp_path / "obs"
    subprocess.run([cc, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-o", str(exe),
                    str(tmp_path / "main.c"), str(tmp_path / "ncs_observer.c")], check=True)
    tr = simulate(fam, res.gains, 3, x0=[1.0, -0.5], steps=150, seed=11, observer_gains=res.observer_gains,
                  sensor_n_drop=2, sensor_loss=0.4, control_loss=0.3, plant_switching="per_sample")
    lines = [str(150)]
    for k in range(150):
        y = fam.C[tr.mode[k]] @ tr.state[k]
        lines.append(f"{tr.mode[k]} {int(tr.sensor_arrived[k])} " + " ".join(repr(float(v)) for v in y) + " "
                     + " ".join(repr(float(v)) for v in tr.input[k]))
    out = subprocess.run([str(exe)], input="\n".join(lines), capture_output=True, text=True, check=True).stdout
    est = np.array([[float(v) for v in line.split()] for line in out.strip().splitlines()])
    scale = np.max(np.abs(tr.estimate[:150]))
    assert np.max(np.abs(est - tr.estimate[:150])) <= 1e-12 * scale


def test_output_channel_without_losses_is_the_lqg_cost():
    from solver import Channel, analyze_channel

    fam = motor(modes=1)
    Q, R = np.diag([1.0, 2.0]), np.eye(1)
    W, V = np.diag([0.1, 0.2]), 0.05 * np.eye(1)
    res = design(fam, 1, feedback="output", sensor_n_drop=1, objective="cost", weights=(Q, R), noise=(W, V))
    rep = analyze_channel(fam, res.gains, 1, Channel.bernoulli(0.0), observer_gains=res.observer_gains,
                          sensor_channel=Channel.bernoulli(0.0), weights=(Q, R), noise=(W, V))
    assert rep.ms_stable is True
    assert rep.stationary_cost == pytest.approx(lqg_cost(fam, res.gains, res.observer_gains, (Q, R), (W, V)),
                                                rel=1e-9)


@pytest.mark.parametrize("a", [1.2, 1.5])
def test_output_channel_breaks_at_the_critical_arrival(a):
    from solver import Channel
    from solver.observer import analyze_output_channel

    fam = PlantFamily(F=[[[a]]], G=[[[1.0]]], C=[[2.0]])
    crit = 1.0 - 1.0 / a**2  # Sinopoli et al.: deadbeat observer and controller, lossless control link
    for arrival, stable in ((crit + 0.02, True), (crit - 0.02, False)):
        rep = analyze_output_channel(fam, [[[-a]]], 1, [[[0.5]]], Channel.bernoulli(1.0 - arrival),
                                     Channel.bernoulli(0.0), noise=(np.eye(1), np.eye(1)))
        assert rep.ms_stable is stable


def test_output_channel_cost_against_monte_carlo():
    """Stationary cost with losses on both links and noise, against a long seeded run of the loop equations."""
    from solver import Channel
    from solver.observer import analyze_output_channel

    fam = PlantFamily(F=[[[1.2, 0.3], [0.0, 0.9]]], G=[[[0.0], [1.0]]], C=[[1.0, 0.0]])
    res = design(fam, 3, feedback="output", sensor_n_drop=3)
    assert res.outcome == "stabilized"
    K, L = res.gains, res.observer_gains
    sensor, control = Channel.bernoulli(0.4), Channel.gilbert_elliott(p_gb=0.1, p_bg=0.4, loss_good=0.05,
                                                                       loss_bad=0.7)
    Q, R = np.eye(2), 0.5 * np.eye(1)
    W, V = np.diag([0.001, 0.001]), np.array([[0.1]])
    rep = analyze_output_channel(fam, K, 3, L, sensor, control, exhausted="hold", weights=(Q, R), noise=(W, V))
    assert rep.ms_stable is True
    rng = np.random.default_rng(5)
    steps, burn = 400_000, 2_000
    F, G, C = fam.F[0], fam.G[0], fam.C[0]
    x, xh, s, d, cc = np.zeros(2), np.zeros(2), np.zeros(2), 0, 0
    Tc = np.asarray(control.transition)
    lossc = np.asarray(control.loss)
    w = rng.multivariate_normal(np.zeros(2), W, size=steps)
    v = rng.normal(0.0, np.sqrt(V[0, 0]), size=steps)
    us, ys, uc, un = rng.random(steps), rng.random(steps), rng.random(steps), rng.random(steps)
    costs = np.empty(steps)
    for k in range(steps):
        if us[k] >= 0.4:
            xh = xh + L[0] @ (C @ x + v[k:k + 1] - C @ xh)
        if uc[k] >= lossc[cc]:
            s, d = xh.copy(), 0
        else:
            d = min(d + 1, 3)
        u = K[min(d, 2)] @ s
        costs[k] = x @ Q @ x + u @ R @ u
        x = F @ x + G @ u + w[k]
        xh = F @ xh + G @ u
        cc = int(un[k] >= Tc[cc, 0]) if cc == 0 else int(un[k] >= Tc[cc, 0])
    batches = costs[burn:].reshape(100, -1).mean(axis=1)
    mean, half = batches.mean(), 4.0 * batches.std(ddof=1) / np.sqrt(len(batches))
    assert abs(rep.stationary_cost - mean) <= half, (rep.stationary_cost, mean, half)
    # The run tells a wrong model apart: without the sensor losses the cost is about 10 % higher.
    wrong = analyze_output_channel(fam, K, 3, L, Channel.bernoulli(0.0), control, exhausted="hold", weights=(Q, R),
                                   noise=(W, V)).stationary_cost
    assert abs(wrong - mean) > half


def test_trace_figure_draws_the_estimate():
    from solver.plotting import render, trace_figure

    fam = motor()
    res = design(fam, 3, feedback="output", sensor_n_drop=2)
    tr = simulate(fam, res.gains, 3, x0=[1.0, 0.0], steps=40, seed=2, observer_gains=res.observer_gains)
    fig = trace_figure([tr], family=fam)
    labels = [line.get_label() for ax in fig.axes for line in ax.get_lines()]
    assert sum("estimate" in lab for lab in labels) == fam.n_states
    assert render(fig, "svg").startswith(b"<?xml")


def test_certified_error_covariance_bound():
    from solver.observer import error_covariance_bound

    fam = motor(modes=1)
    W, V = np.diag([0.1, 0.2]), 0.05 * np.eye(1)
    F, C = fam.F[0], fam.C[0]
    P = riccati_by_iteration(F.T, C.T, W, V)
    L = P @ C.T @ np.linalg.inv(C @ P @ C.T + V)
    Sigma = P - L @ C @ P  # the Kalman filter's steady-state filtered covariance
    X = error_covariance_bound(fam, L[None], 1, (W, V))
    assert np.allclose(X[0], Sigma, rtol=1e-5, atol=1e-9)  # without losses the bound is the Kalman covariance
    # With losses: the covariance recursion along random admissible patterns stays below the bound.
    fam3 = motor()
    res = design_observer(fam3, 3, noise=(W, V))
    assert res.outcome == "certified" and res.error_bound is not None
    Lm, Xb = res.gains, res.error_bound
    rng = np.random.default_rng(3)
    for _ in range(100):
        S, lost, l = np.zeros((2, 2)), 0, int(rng.integers(3))
        for _k in range(60):
            l_next = int(rng.integers(3))
            got = lost == 2 or rng.random() < 0.5
            S = fam3.F[l] @ S @ fam3.F[l].T + W
            if got:
                g = np.eye(2) - Lm[l_next] @ fam3.C[l_next]
                S = g @ S @ g.T + Lm[l_next] @ V @ Lm[l_next].T
            lost = 0 if got else lost + 1
            l = l_next
            assert np.linalg.eigvalsh(Xb[lost] - S)[0] >= -1e-12
