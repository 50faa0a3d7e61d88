"""Estimated cost of the analyses (simulation, channel analysis, critical loss, fixed-gain analysis), checked
before any work starts.

:func:`solver.design` refuses a design over its budget from :func:`solver.compiled.design_size`; the functions
here give :func:`solver.simulate`, :func:`solver.analyze_channel`, :func:`solver.critical_loss` and
:func:`solver.analyze` the same guard with the same defaults (:data:`solver.compiled.MAX_SOLVER_MEMORY`,
4 GiB or ``NCS_SOLVER_MAX_MEMORY``; :data:`solver.compiled.MAX_SOLVER_SECONDS`, 300 s or
``NCS_SOLVER_MAX_SECONDS``) and the same options, ``max_memory=`` (bytes) and ``time_limit=`` (seconds).
A call over a budget raises :class:`solver.InvalidInput` naming the size that makes it large, the estimate and
the limit, before anything is allocated.

The estimates are made to refuse only calls that surely run over budget (they err low in time):

* simulation: about ``1e-4`` s and ``8 (n + m + 10)`` bytes per sample (measured 2-5e-4 s and 120 B per
  sample for a 4-state, 1-input cart-pole on the 2-core development machine);
* channel analysis: the second-moment operator's size ``s`` (the sum over the jump-system modes of the squared
  state dimension, the service's ``NCS_MAX_CHANNEL_SIZE``): about ``5e-4 s`` and 16 KiB per unit of ``s``
  per spectral-radius estimate (measured 45,360 -> 40 s and 0.77 GB for a whole analysis; 512 -> 0.6 s);
  :func:`solver.critical_loss` makes one estimate per bisection step.
"""

from __future__ import annotations

import math

from .errors import InvalidInput

SIMULATION_SECONDS_PER_SAMPLE = 1e-4
CHANNEL_SECONDS_PER_SIZE = 5e-4
CHANNEL_BYTES_PER_SIZE = 16 * 1024


def _bytes(x: float) -> str:
    return f"{x / 2**30:.3g} GiB" if x >= 2**30 else f"{x / 2**20:.3g} MiB"


def budgets(max_memory, time_limit) -> tuple[float, float, str, str]:
    """(bytes, seconds, name of the memory limit, name of the time limit) after the defaults."""
    from .compiled import MAX_SOLVER_MEMORY, MAX_SOLVER_SECONDS

    for name, value in (("max_memory", max_memory), ("time_limit", time_limit)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not value > 0 or math.isnan(value)):
            raise InvalidInput(f"{name} must be a positive number", (name,))
    memory = float(MAX_SOLVER_MEMORY if max_memory is None else max_memory)
    seconds = float(MAX_SOLVER_SECONDS if time_limit is None else time_limit)
    return (memory, seconds, "NCS_SOLVER_MAX_MEMORY, or give max_memory=" if max_memory is None else "max_memory=",
            "NCS_SOLVER_MAX_SECONDS, or give time_limit=" if time_limit is None else "time_limit=")


def check_estimate(what: str, seconds: float, memory: float, field: tuple, hint: str,
                   max_memory=None, time_limit=None) -> None:
    """Raise InvalidInput when ``what`` would take over the time or memory budget."""
    max_bytes, max_seconds, memory_name, seconds_name = budgets(max_memory, time_limit)
    if max_bytes and memory > max_bytes:
        raise InvalidInput(f"{what} would need about {_bytes(memory)} of memory, over the limit of "
                           f"{_bytes(max_bytes)} ({memory_name}): {hint}", field)
    if seconds > max_seconds:
        raise InvalidInput(f"{what} would take about {seconds:.3g} s, over the limit of {max_seconds:g} s "
                           f"({seconds_name}): {hint}", field)


def check_simulation(steps: int, n: int, m: int, max_memory=None, time_limit=None) -> None:
    seconds = steps * SIMULATION_SECONDS_PER_SAMPLE
    memory = steps * 8.0 * (n + m + 10)
    check_estimate(f"the simulation of steps = {steps} samples", seconds, memory, ("steps",),
                   "simulate fewer steps", max_memory, time_limit)


def channel_operator_size(channel_states: int, n_modes: int, n_drop: int, n: int) -> int:
    """Upper bound on the channel analysis's operator size, ``c r (n_drop + 1) (2 n)^2`` (as the service)."""
    return int(channel_states) * int(n_modes) * (int(n_drop) + 1) * (2 * int(n)) ** 2


def channel_estimate(size: int, radius_estimates: int = 1) -> tuple[float, float]:
    """(seconds, bytes) of a channel analysis whose operator has size ``size``."""
    return radius_estimates * size * CHANNEL_SECONDS_PER_SIZE, size * float(CHANNEL_BYTES_PER_SIZE)


def check_channel(what: str, size: int, radius_estimates: int = 1, max_memory=None, time_limit=None) -> None:
    seconds, memory = channel_estimate(size, radius_estimates)
    runs = "" if radius_estimates == 1 else f", {radius_estimates} spectral-radius estimates"
    check_estimate(f"{what} has an operator of size up to {size}{runs}; it", seconds, memory, ("channel",),
                   "use a smaller n_drop, fewer channel states or fewer plant modes", max_memory, time_limit)
