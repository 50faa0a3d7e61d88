"""Benchmark cases: the paper's example and seeded random switched families."""

from __future__ import annotations

import numpy as np

from solver import PlantFamily


def random_family(n: int, r: int, m: int, seed: int, rho=(1.0, 1.2), spread: float = 0.3) -> PlantFamily:
    """r modes scattered around one random nominal plant, each unstable (spectral radius in ``rho``).

    ``F_l = s_l (F_0 + spread E_l)`` scaled so its spectral radius is drawn from
    ``rho``; ``G_l = G_0 + spread E'_l`` (Gaussian, full column rank almost
    surely).  Independent random modes are almost never stabilizable by common
    gains; modes near a nominal plant are, for some seeds (checked by ``lmi``).
    """
    rng = np.random.default_rng(seed)
    F0 = rng.standard_normal((n, n))
    G0 = rng.standard_normal((n, m))
    Fs, Gs = [], []
    for _ in range(r):
        F = F0 + spread * rng.standard_normal((n, n))
        F *= rng.uniform(*rho) / np.max(np.abs(np.linalg.eigvals(F)))
        Fs.append(F)
        Gs.append(G0 + spread * rng.standard_normal((n, m)))
    return PlantFamily(F=Fs, G=Gs, name=f"random n={n} r={r} m={m} seed={seed}")


#: name -> (description, family builder, n_drop, methods).  Seeds were picked so that
#: ``design(..., method="lmi").outcome == "stabilized"`` (the benchmark re-checks it).
CASES = {
    "paper": ("paper example h=0.1 (n=2, r=3, m=1)", lambda: PlantFamily.paper_example(0.1), 3, ("lmi", "ccl")),
    "n4": ("random n=4, r=3, m=2, seed 2", lambda: random_family(4, 3, 2, seed=2, spread=0.3), 6, ("lmi", "ccl")),
    "n8": ("random n=8, r=4, m=2, seed 0", lambda: random_family(8, 4, 2, seed=0, spread=0.2), 8, ("lmi", "ccl")),
    "n20": ("random n=20, r=5, m=2, seed 0", lambda: random_family(20, 5, 2, seed=0, spread=0.1), 10, ("lmi",)),
}


def shape(family: PlantFamily, n_drop: int) -> str:
    return f"n={family.n_states} m={family.n_inputs} r={family.n_modes} N={n_drop}"
