"""Textbook plants from the Control Tutorials for MATLAB and Simulink (CTMS), as a new user would enter them
(continuous-time matrices from tests/solver/plants.py, discretized by ``PlantFamily.from_continuous``).

* ``pendulum``: the inverted pendulum on a cart (M = 0.5 kg, m = 0.2 kg, b = 0.1 N s/m, I = 0.006 kg m^2,
  l = 0.3 m to the centre of mass); states x (m), x' (m/s), phi (rad), phi' (rad/s); input the force F (N).
  ``lengths`` gives one plant mode per pole length (the "two-pole" family: 0.3 m and 0.35 m).
  Its fastest unstable pole is about 5.57 rad/s at l = 0.3 m: time constant 0.18 s.
* ``quarter_car``: the bus suspension (M2 = 320 kg, K1 = 80,000 N/m, K2 = 500,000 N/m, b1 = 350 N s/m,
  b2 = 15,020 N s/m), one plant mode per body mass M1 (the "two loads": 2,500 kg and 3,500 kg); states
  x1 (m), x1' (m/s), y1 = x1 - x2 (m), y1' (m/s); input the actuator force U (N). Stable without control.
"""

from __future__ import annotations

from solver import PlantFamily

from .plants import bus_ct, pendulum_ct


def pendulum_matrices(length: float = 0.3):
    """The continuous-time ``(A, B)`` as nested lists (what a user types), pole length ``length`` (m)."""
    A, B = pendulum_ct(l=length)
    return A.tolist(), B.tolist()


def pendulum(sampling_period: float = 0.01, lengths=(0.3, 0.35)) -> PlantFamily:
    A, B = zip(*(pendulum_matrices(length) for length in lengths))
    return PlantFamily.from_continuous(list(A), list(B), sampling_period, state_names=["x", "v", "phi", "omega"],
                                       input_names=["F"], units={"x": "m", "v": "m/s", "phi": "rad",
                                                                  "omega": "rad/s", "F": "N"})


def pendulum_plant_json(sampling_period: float = 0.01, lengths=(0.3, 0.35)) -> dict:
    A, B = zip(*(pendulum_matrices(length) for length in lengths))
    return {"kind": "continuous", "A": [list(a) for a in A], "B": [list(b) for b in B],
            "sampling_period": sampling_period}


def quarter_car_matrices(M1: float = 2500.0):
    """The continuous-time ``(A, B)`` (actuator force only) as nested lists, body mass ``M1`` (kg)."""
    A, B, _ = bus_ct(m1=M1)
    return A.tolist(), B.tolist()


def quarter_car(sampling_period: float = 0.01, loads=(2500.0, 3500.0)) -> PlantFamily:
    A, B = zip(*(quarter_car_matrices(M1) for M1 in loads))
    return PlantFamily.from_continuous(list(A), list(B), sampling_period, state_names=["x1", "v1", "y1", "w1"],
                                       input_names=["U"], units={"x1": "m", "v1": "m/s", "y1": "m", "w1": "m/s",
                                                                  "U": "N"})
