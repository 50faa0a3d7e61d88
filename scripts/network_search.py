"""Search for a family that has no design for bounded_drops(3) (Farkas proof) but a certified one for
weakly_hard(2, 5, 3) (the Done-means example of issue 28; tests/solver/test_network_design.py uses the result).

    python3 scripts/network_search.py [--seed 0] [--tries 300] [--states 1] [--modes 2]

Prints every hit as a PlantFamily literal.  Random families rarely hit; the example the tests use was built
by hand instead (docs/design.md, "Design on a network"): x+ = a x + b_l u with a = 1.3 and b in {1.5, 0.5}
(per-interval plant switching).  With ``c_eta = sum_t a^t K_{eta-t}`` (free for each eta),
``min_c max_l |a^eta + b_l c| = a^eta (rho - 1)/(rho + 1)`` with ``rho = b_1/b_2 = 3``: 0.65, 0.845 and 1.0985 for
eta = 1, 2, 3.  So no gains make three-sample intervals contract (bounded_drops(3): infeasible), while on
weakly_hard(2, 5, 3) every three-sample interval is followed by two one-sample ones (1.0985 * 0.65^2 < 1).  Random discrete-time families whose largest open-loop spectral radius is in [1, 2].
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from solver import Network, PlantFamily, design


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tries", type=int, default=300)
    ap.add_argument("--states", type=int, default=1)
    ap.add_argument("--modes", type=int, default=2)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    net = Network.weakly_hard(2, 5, 3)
    n, r = args.states, args.modes
    warnings.simplefilter("ignore")
    for i in range(args.tries):
        # near the edge: spectral radius of F in [1, 2], so that three-sample intervals are hard
        F = rng.uniform(-1, 1, (r, n, n))
        F = np.round(F * rng.uniform(1.0, 2.0) / max(max(abs(np.linalg.eigvals(f))) for f in F), 2)
        G = np.round(rng.uniform(-1, 1, (r, n, 1)), 2)
        fam = PlantFamily(list(F), list(G))
        base = design(fam, 3, decay_rate=None)
        if base.outcome != "infeasible":
            continue
        res = design(fam, network=net, decay_rate=None)
        print(i, base.outcome, res.outcome, flush=True)
        if res.outcome == "stabilized":
            print("HIT F =", F.tolist(), "G =", G.tolist(), flush=True)


if __name__ == "__main__":
    main()
