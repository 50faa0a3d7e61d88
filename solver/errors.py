"""Exceptions raised by the solver library.

Two kinds of failure are kept apart on purpose: bad input from the caller
(:class:`InvalidInput`, a ``ValueError`` that names the offending field) and
a numerical back end that could not produce an answer
(:class:`SolverFailed`, a ``RuntimeError``).  A design that is *proved*
infeasible is neither: it is an ordinary result with ``outcome="infeasible"``.
"""

from __future__ import annotations


class InvalidInput(ValueError):
    """Input that cannot describe a valid problem.

    Parameters
    ----------
    message : str
        Human-readable explanation.
    field : tuple
        Path of the offending field, e.g. ``("A", 1)`` for the second matrix
        of ``A`` or ``("sampling_period",)``.  Services map it to a JSON
        pointer or a pydantic ``loc``.
    """

    def __init__(self, message: str, field: tuple = ()):
        super().__init__(message)
        self.field = tuple(field)


class SolverFailed(RuntimeError):
    """The conic solver ended without a usable answer (numerical failure, time limit).

    This is never turned into ``outcome="infeasible"``: only a solved problem
    can prove infeasibility.
    """

    def __init__(self, message: str, status: str | None = None):
        super().__init__(message)
        self.status = status
