"""A cart-pole whose pole length switches (0.2, 0.3, 0.4 m): 4 states, 3 plant modes, h = 0.02 s.

Linearized about the upright pole (cart mass 1 kg, point mass 0.1 kg at the pole's end, g = 9.81 m/s^2);
states x (m), x' (m/s), theta (rad), theta' (rad/s), input a force (N).
"""

from __future__ import annotations

from solver import PlantFamily

LENGTHS = (0.2, 0.3, 0.4)


def cartpole(lengths=LENGTHS, sampling_period: float = 0.02, cart: float = 1.0, pole: float = 0.1,
             g: float = 9.81) -> PlantFamily:
    A, B = [], []
    for length in lengths:
        A.append([[0, 1, 0, 0], [0, 0, -pole * g / cart, 0], [0, 0, 0, 1],
                  [0, 0, (cart + pole) * g / (cart * length), 0]])
        B.append([[0], [1 / cart], [0], [-1 / (cart * length)]])
    return PlantFamily.from_continuous(A, B, sampling_period, state_names=["x", "v", "theta", "omega"],
                                       input_names=["F"],
                                       units={"x": "m", "v": "m/s", "theta": "rad", "omega": "rad/s", "F": "N"},
                                       mode_names=[f"pole {length:g} m" for length in lengths])
