"""Textbook plants (Control Tutorials for MATLAB and Simulink, CTMS), discretized by zero-order hold.

* :func:`pendulum`: the CTMS inverted pendulum on a cart (M = 0.5 kg cart, m = 0.2 kg pendulum, b = 0.1 N s/m
  friction, l = 0.3 m to the centre of mass, I = 0.006 kg m^2, g = 9.8 m/s^2), states x (m), x' (m/s),
  phi (rad), phi' (rad/s), input the force F (N).  ``masses`` gives one plant mode per pendulum mass.
* :func:`bus_suspension`: the CTMS quarter-car bus suspension (m1 = 2500 kg, m2 = 320 kg, k1 = 80000 N/m,
  k2 = 500000 N/m, b1 = 350 N s/m, b2 = 15020 N s/m), states x1, x1', y1 = x1 - x2, y1', input the actuator
  force U (N); the road W (m) is the disturbance (second column of the CTMS input matrix).

Both are discretized with ``scipy.signal.cont2discrete`` (zero-order hold), independently of
:meth:`PlantFamily.from_continuous`.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from solver import PlantFamily

#: The CTMS state weights of the LQR pendulum example (R = 1).
PENDULUM_Q = np.diag([5000.0, 0.0, 100.0, 0.0])


def pendulum_ct(M: float = 0.5, m: float = 0.2, b: float = 0.1, l: float = 0.3, I: float = 0.006,
                g: float = 9.8) -> tuple[np.ndarray, np.ndarray]:
    p = I * (M + m) + M * m * l**2
    A = np.array([[0, 1, 0, 0],
                  [0, -(I + m * l**2) * b / p, m**2 * g * l**2 / p, 0],
                  [0, 0, 0, 1],
                  [0, -m * l * b / p, m * g * l * (M + m) / p, 0]])
    B = np.array([[0], [(I + m * l**2) / p], [0], [m * l / p]])
    return A, B


def bus_ct(m1: float = 2500.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B_u, B_w)``: the actuator force's and the road's input columns; ``m1`` the body mass (kg)."""
    m2, k1, k2, b1, b2 = 320.0, 80000.0, 500000.0, 350.0, 15020.0
    A = np.array([[0, 1, 0, 0],
                  [-b1 * b2 / (m1 * m2), 0, (b1 / m1) * (b1 / m1 + b1 / m2 + b2 / m2) - k1 / m1, -b1 / m1],
                  [b2 / m2, 0, -(b1 / m1 + b1 / m2 + b2 / m2), 1],
                  [k2 / m2, 0, -(k1 / m1 + k1 / m2 + k2 / m2), 0]])
    B = np.array([[0, 0], [1 / m1, b1 * b2 / (m1 * m2)], [0, -b2 / m2], [1 / m1 + 1 / m2, -k2 / m2]])
    return A, B[:, :1], B[:, 1:]


def zoh(A, B, h: float) -> tuple[np.ndarray, np.ndarray]:
    n = A.shape[0]
    F, G, *_ = scipy.signal.cont2discrete((A, B, np.eye(n), np.zeros((n, B.shape[1]))), h, method="zoh")
    return F, G


def pendulum(masses=(0.2,), h: float = 0.01) -> PlantFamily:
    Fs, Gs = zip(*(zoh(*pendulum_ct(m=mass), h) for mass in masses))
    return PlantFamily(F=np.array(Fs), G=np.array(Gs), sampling_period=h, name="CTMS inverted pendulum")


def bus_suspension(h: float = 0.01) -> tuple[PlantFamily, np.ndarray]:
    """The family and the road's discretized input column E (n x 1)."""
    A, Bu, Bw = bus_ct()
    F, G = zoh(A, np.hstack([Bu, Bw]), h)
    return PlantFamily(F=F[None], G=G[None, :, :1], sampling_period=h, name="CTMS bus suspension"), G[:, 1:]
