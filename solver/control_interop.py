"""python-control in and out: plant modes and designed closed loops as ``control.StateSpace``.

python-control is an optional dependency (``pip install "ncs-design[control]"``); this module
imports it when called.  The way in is :meth:`solver.PlantFamily.from_statespace`.

Closed loops follow docs/design.md: between two effective packets ``eta`` samples apart the
buffer plays ``u(i_m + q - 1) = K_q x(i_m)``, so with plant mode l the state at the packet
instants obeys ``x(i_{m+1}) = A_{l,eta}(K) x(i_m)`` with::

    A_{l,eta}(K) = F_l^eta + sum_{t=0}^{eta-1} F_l^t G_l K_{eta-t}

``eta = 1`` (no loss) is the ordinary sampled loop ``F_l + G_l K_1``.
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidInput
from .network import check_gains
from .plant import PlantFamily


def _control():
    try:
        import control
    except ImportError:  # pragma: no cover - depends on the installation
        raise ImportError('python-control is not installed: pip install "ncs-design[control]"') from None
    return control


def _names(family: PlantFamily) -> tuple[list[str], list[str]]:
    states = list(family.state_names or [f"x{i + 1}" for i in range(family.n_states)])
    inputs = list(family.input_names or [f"u{j + 1}" for j in range(family.n_inputs)])
    return states, inputs


def plant_systems(family: PlantFamily) -> list:
    """Each plant mode as a discrete python-control system ``x(k+1) = F_l x(k) + G_l u(k)``, ``y = x``.

    Parameters
    ----------
    family : PlantFamily

    Returns
    -------
    list of control.StateSpace, length r
        ``dt`` is the family's sampling period in seconds (``True``, "unspecified", when it has
        none); states, inputs and outputs carry the family's names; system ``l`` is named
        ``"mode l"`` (0-based, as everywhere in the library).
    """
    ct = _control()
    states, inputs = _names(family)
    dt = family.sampling_period if family.sampling_period is not None else True
    n = family.n_states
    return [ct.ss(family.F[l], family.G[l], np.eye(n), np.zeros((n, family.n_inputs)), dt,
                  states=states, inputs=inputs, outputs=states, name=f"mode {l}")
            for l in range(family.n_modes)]


def interval_closed_loop(family: PlantFamily, gains, eta: int = 1) -> np.ndarray:
    """``A_{l,eta}(K)`` for every plant mode: the state map over an interval of ``eta`` samples.

    Parameters
    ----------
    family : PlantFamily
    gains : array_like, shape (n_drop, m, n)
        ``gains[q-1] = K_q``.
    eta : int
        Samples between the two effective packets, ``1 <= eta <= n_drop`` (``eta - 1`` losses).

    Returns
    -------
    ndarray, shape (r, n, n)
    """
    try:
        n_drop = len(gains)
    except TypeError:
        raise InvalidInput("gains must be a list of n_drop matrices m x n, K_1 first", ("gains",)) from None
    K = check_gains(gains, n_drop, family.n_inputs, family.n_states)
    if isinstance(eta, bool) or not isinstance(eta, (int, np.integer)) or not 1 <= eta <= n_drop:
        raise InvalidInput(f"eta must be an integer in 1..n_drop = {n_drop}, got {eta!r}", ("eta",))
    out = np.empty((family.n_modes, family.n_states, family.n_states))
    for l in range(family.n_modes):
        F, G = family.F[l], family.G[l]
        acc = np.linalg.matrix_power(F, eta)
        Ft = np.eye(family.n_states)
        for t in range(eta):  # F^t G K_{eta-t}
            acc = acc + Ft @ G @ K[eta - t - 1]
            Ft = Ft @ F
        out[l] = acc
    return out


def closed_loop_systems(family: PlantFamily, gains, eta: int = 1) -> list:
    """Each plant mode's designed closed loop as a python-control system.

    Parameters
    ----------
    family : PlantFamily
    gains : array_like, shape (n_drop, m, n)
        ``gains[q-1] = K_q``, e.g. ``design(...).gains``.
    eta : int, default 1
        ``1``: the loop without losses, ``x(k+1) = (F_l + G_l K_1) x(k) + G_l d(k)`` sampled every h,
        with the plant-input disturbance ``d`` as input and outputs ``x`` and ``u = K_1 x``.
        ``eta > 1``: the map between packets ``eta`` samples apart, ``x(i_{m+1}) = A_{l,eta} x(i_m)``,
        a system with no input, output ``x`` and ``dt = eta h``.

    Returns
    -------
    list of control.StateSpace, length r
        Named ``"closed loop, mode l"``; states and outputs carry the family's names.

    Examples
    --------
    >>> import control as ct
    >>> loops = closed_loop_systems(fam, res.gains)          # doctest: +SKIP
    >>> resp = ct.initial_response(loops[0], X0=[1.0, 0.0])  # doctest: +SKIP
    """
    ct = _control()
    A = interval_closed_loop(family, gains, eta)
    K1 = check_gains(gains, len(gains), family.n_inputs, family.n_states)[0]
    states, inputs = _names(family)
    n, m = family.n_states, family.n_inputs
    h = family.sampling_period
    out = []
    for l in range(family.n_modes):
        if eta == 1:
            sys = ct.ss(A[l], family.G[l], np.vstack([np.eye(n), K1]), np.zeros((n + m, m)),
                        h if h is not None else True, states=states, inputs=[f"d_{u}" for u in inputs],
                        outputs=states + inputs, name=f"closed loop, mode {l}")
        else:
            sys = ct.ss(A[l], np.zeros((n, 0)), np.eye(n), np.zeros((n, 0)),
                        eta * h if h is not None else True, states=states, outputs=states,
                        name=f"closed loop, mode {l}, eta {eta}")
        out.append(sys)
    return out
