"""Textbook plants from the Control Tutorials for MATLAB and Simulink (CTMS), as a new user would enter them.

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


def pendulum_matrices(length: float = 0.3, M: float = 0.5, m: float = 0.2, b: float = 0.1, inertia: float = 0.006,
                      g: float = 9.8):
    p = inertia * (M + m) + M * m * length**2
    A = [[0, 1, 0, 0],
         [0, -(inertia + m * length**2) * b / p, (m**2 * g * length**2) / p, 0],
         [0, 0, 0, 1],
         [0, -(m * length * b) / p, m * g * length * (M + m) / p, 0]]
    B = [[0], [(inertia + m * length**2) / p], [0], [m * length / p]]
    return A, B


def pendulum(sampling_period: float = 0.01, lengths=(0.3, 0.35)) -> PlantFamily:
    A, B = zip(*(pendulum_matrices(length) for length in lengths))
    return PlantFamily.from_continuous(list(A), list(B), sampling_period, state_names=["x", "v", "phi", "omega"],
                                       input_names=["F"], units={"x": "m", "v": "m/s", "phi": "rad",
                                                                  "omega": "rad/s", "F": "N"})


def pendulum_plant_json(sampling_period: float = 0.01, lengths=(0.3, 0.35)) -> dict:
    A, B = zip(*(pendulum_matrices(length) for length in lengths))
    return {"kind": "continuous", "A": [list(a) for a in A], "B": [list(b) for b in B],
            "sampling_period": sampling_period}


def quarter_car_matrices(M1: float = 2500.0, M2: float = 320.0, K1: float = 80000.0, K2: float = 500000.0,
                         b1: float = 350.0, b2: float = 15020.0):
    A = [[0, 1, 0, 0],
         [-(b1 * b2) / (M1 * M2), 0, (b1 / M1) * ((b1 / M1) + (b1 / M2) + (b2 / M2)) - K1 / M1, -(b1 / M1)],
         [b2 / M2, 0, -((b1 / M1) + (b1 / M2) + (b2 / M2)), 1],
         [K2 / M2, 0, -((K1 / M1) + (K1 / M2) + (K2 / M2)), 0]]
    B = [[0], [1 / M1], [0], [(1 / M1) + (1 / M2)]]
    return A, B


def quarter_car(sampling_period: float = 0.01, loads=(2500.0, 3500.0)) -> PlantFamily:
    A, B = zip(*(quarter_car_matrices(M1) for M1 in loads))
    return PlantFamily.from_continuous(list(A), list(B), sampling_period, state_names=["x1", "v1", "y1", "w1"],
                                       input_names=["U"], units={"x1": "m", "v1": "m/s", "y1": "m", "w1": "m/s",
                                                                  "U": "N"})
