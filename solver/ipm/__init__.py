"""A structure-exploiting primal-dual interior-point solver for the design LMIs (docs/design.md).

Every SDP the design methods solve has the form::

    maximize   t
    subject to B_b(V) - t I >= 0,   b = 1..nb        (all blocks of one side k)
               one linear equality on V (the normalization, e.g. trace W = n)

where ``V`` is a handful of matrix variables (symmetric ``W``, general
``Y``, ...) and every block is a sum of terms ``c (L V R + (L V R)^T)`` plus
a constant.  A general conic solver keeps each block's scaling as a dense
``(k(k+1)/2)^2`` matrix in its KKT system; here the Schur complement
``M_ij = sum_b tr(A_i X_b A_j S_b^{-1})`` (HKM direction) is assembled from
Kronecker products of small ``L^T G L'``, ``R X R'^T`` pieces: the sum over
the blocks of ``kron(P_b, Q_b)`` is ONE matrix product
``P^T Q`` of the blocks' vectorized pieces (``P`` of shape (nb, r r'),
``Q`` of shape (nb, c c')), so the cost is ``O(nb n^4)`` BLAS-3 work instead
of ``O(nb k^6)``.

The solver works on the standard pair (``y`` the free variables left after
eliminating the equality, ``X_b`` the block multipliers)::

    (D)  max b^T y   s.t.  S = C + A(y) >= 0
    (P)  min <C, X>  s.t.  A^*(X) + b = 0,  X >= 0

with an infeasible start (``S`` starts strictly feasible, ``X = I / (nb k)``
does not satisfy ``A^*(X) + b = 0``), the HKM symmetrized direction and
Mehrotra's predictor-corrector, separate primal and dual step lengths, and
stops on relative gap and relative primal/dual infeasibility.  Because the
``y`` iterates stay feasible (``S > 0``), ``t = b^T y`` is always an
*attained* value: a returned ``t > margin`` is backed by a feasible
``(W, Y)`` whatever the status; ``<C, X>`` bounds ``t*`` from above once
the primal residual is small.

Public entry points: :func:`solve_lmi` (the ``lmi`` design),
:func:`solve_switched` (the ``switched`` design), :func:`solve_common_fixed_gain`
(the fixed-gain certificate LMI of ``analyze``), and the generic
:class:`BlockLMI` / :func:`solve_block_lmi` they are built on.
"""

from .algorithm import GroupedSolution, IPMOptions, IPMSolution, WarmStart, solve_block_lmi, solve_grouped
from .blas import blas_threads, heap_reuse
from .design_blocks import (LMISolution, SwitchedSolution, _gain_L, _gain_scale, _split_Y,  # noqa: F401 (ccl)
                            design_solve, design_solve_fixed_gain, lmi_problem, solve_common_fixed_gain, solve_lmi,
                            solve_switched, switched_problem)
from .model import BlockGroup, BlockLMI, GroupedLMI, MatrixVariable
from .network_blocks import NetworkIPMSolution, network_problem, solve_network
from .performance_blocks import PerformanceProblem, PerformanceSolution, performance_problem, solve_performance

__all__ = [
    "MatrixVariable",
    "BlockLMI",
    "BlockGroup",
    "GroupedLMI",
    "GroupedSolution",
    "NetworkIPMSolution",
    "network_problem",
    "solve_network",
    "PerformanceProblem",
    "PerformanceSolution",
    "performance_problem",
    "solve_performance",
    "solve_grouped",
    "IPMOptions",
    "IPMSolution",
    "WarmStart",
    "LMISolution",
    "SwitchedSolution",
    "design_solve",
    "design_solve_fixed_gain",
    "blas_threads",
    "heap_reuse",
    "solve_block_lmi",
    "solve_lmi",
    "solve_switched",
    "solve_common_fixed_gain",
    "lmi_problem",
    "switched_problem",
]
