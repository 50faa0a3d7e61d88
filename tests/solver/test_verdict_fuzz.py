"""No verdict of ``design`` is contradicted by an independent check, over a seeded fuzz.

``NCS_VERDICT_FUZZ`` sets the number of families (default 150, about 15 s); the larger runs and
their counts: ``python scripts/fuzz_verdicts.py``.
"""

import os

from tests.solver.verdict_fuzz import run


def test_no_verdict_is_contradicted():
    count = int(os.environ.get("NCS_VERDICT_FUZZ", "150"))
    verdicts, contradictions = run(count, seed=2026)
    assert contradictions == []
    # the fuzz reaches every kind of verdict (else it would test nothing)
    kinds = {key.split(":", 1)[1] for key in verdicts}
    assert {"stabilized", "infeasible/farkas", "infeasible/uncontrollable"} <= kinds, verdicts
