"""Run the verdict fuzz (tests/solver/verdict_fuzz.py) at a larger count and print the counts.

    python scripts/fuzz_verdicts.py [count] [seed]
"""

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.solver.verdict_fuzz import run  # noqa: E402

if __name__ == "__main__":
    count = int(sys.argv[1]) if len(sys.argv) > 1 else 400
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    start = time.perf_counter()
    verdicts, contradictions = run(count, seed=seed)
    print(f"cases: {count} (seed {seed}), {time.perf_counter() - start:.0f} s")
    for key, value in sorted(verdicts.items()):
        print(f"  {key}: {value}")
    print(f"contradictions: {len(contradictions)}")
    for c in contradictions:
        print("  ", c)
    sys.exit(1 if contradictions else 0)
