"""MATLAB/Octave in and out: designed gains as a ``.mat`` file or an ``.m`` script, plants from ``.mat``.

Variables written (both formats define the same ones):

==============  =====================  ==========================================================
name            size                   meaning
==============  =====================  ==========================================================
``K``           n_drop x m x n         ``K(q,:,:)`` is K_q (the service's ``gains[q-1]``)
``K1..KN``      m x n                  the same gains one by one (no ``squeeze`` needed)
``F``, ``G``    n x n x r, n x m x r   plant modes, MATLAB convention ``F(:,:,l)`` (l = 1..r)
``P``           see ``certificate``    the certificate's matrix: (n n_drop) x (n n_drop) for a
                                       common quadratic one, S x n x n for a switched one;
                                       empty when there is none
``n_drop``      scalar                 at most n_drop - 1 consecutive losses
``outcome``     string                 ``stabilized``, ``infeasible`` or ``not_converged``
``certificate`` string                 the certificate's kind, empty when there is none
``h``           scalar                 the sampling period in seconds (empty when unknown)
``network``     string                 on a network only: what the gains are certified for
                                       (``Network.describe()``, e.g. ``delays(max_delay=2, n_drop=3)``)
``P_node``      V x 1                  on a network only: the automaton node (1-based) of each
                                       ``P(i,:,:)`` of a node-dependent certificate (V matrices)
``node_ages``   V x 1                  on a network only: the buffer age of that node
``P_plant``     V x 1                  analyses on a network: the plant mode (1-based) of ``P(i,:,:)``
==============  =====================  ==========================================================

``F``/``G`` use MATLAB's convention so that a written file is also a plant file for
:func:`plant_from_mat` (and ``ncs-design design gains.mat``).  Plant ``.mat`` files hold either
``A``, ``B`` (continuous, with ``h`` or ``sampling_period`` in the file or given) or ``F``, ``G``
(discrete), each a 3-D array ``n x n x r`` (``F(:,:,l)``), a cell array ``{F1, F2, ...}`` or, for a
single mode, a 2-D matrix.
"""

from __future__ import annotations

import io
import os
from typing import Any

import numpy as np

from .errors import InvalidInput
from .plant import PlantFamily

__all__ = ["matlab_variables", "mat_bytes", "save_mat", "m_script", "plant_from_mat"]


def _get(obj, key: str):
    return obj.get(key) if isinstance(obj, dict) else getattr(obj, key, None)


def _certificate(result) -> tuple[str, np.ndarray]:
    cert = _get(result, "certificate")
    if cert is None:
        return "", np.zeros((0, 0))
    P = _get(cert, "P")
    kind = _get(cert, "kind") or ""
    if P is None or isinstance(P, str):
        return kind, np.zeros((0, 0))
    return kind, np.asarray(P, dtype=float)


def matlab_variables(result, family: PlantFamily | None = None) -> dict[str, Any]:
    """The variables of a design as numpy arrays and strings, in the sizes of the module table.

    Parameters
    ----------
    result : solver.DesignResult or dict
        A library result, or the service's JSON result (``gains``, ``certificate``, ``n_drop``,
        ``outcome`` and, when ``family`` is not given, ``F``, ``G``, ``sampling_period``).
    family : PlantFamily, optional
        The designed plant; required for a library result.

    Returns
    -------
    dict
        ``K``, ``K1``..``KN``, ``F``, ``G``, ``P``, ``n_drop``, ``outcome``, ``certificate``, ``h``; for a
        cost/hinf design also ``perf_kind``, ``perf_upper``, ``perf_lower`` (NaN when none) and ``P_perf`` (and
        ``P_perf_modes``, n x n x S, when one storage per loop mode certifies ``perf_upper``), and with
        ``u_max`` ``X_inv`` (the invariant set ``x' X_inv x <= 1``); for output feedback ``L`` (n x p x r, the
        observer gains), ``C`` (p x n x r), ``P_joint`` and ``Q_joint`` (n x n x sensor_n_drop) of the joint
        certificate (docs/design.md §12).
    """
    if family is not None:
        F, G, h = np.asarray(family.F), np.asarray(family.G), family.sampling_period
    else:
        F, G, h = _get(result, "F"), _get(result, "G"), _get(result, "sampling_period")
        if F is None or G is None:
            raise InvalidInput("the result has no plant matrices F and G: pass the family too", ("family",))
        F, G = np.asarray(F, dtype=float), np.asarray(G, dtype=float)
    n_drop = int(_get(result, "n_drop"))
    gains = _get(result, "gains")
    n, m = F.shape[1], G.shape[2]
    K = np.zeros((n_drop, m, n)) if gains is None else np.asarray(gains, dtype=float).reshape(n_drop, m, n)
    kind, P = _certificate(result)
    out: dict[str, Any] = {"K": K}
    if gains is not None:
        out.update({f"K{q + 1}": K[q] for q in range(n_drop)})
    out.update({
        "F": np.moveaxis(F, 0, -1),  # (r, n, n) -> n x n x r
        "G": np.moveaxis(G, 0, -1),
        "P": P,
        "n_drop": float(n_drop),
        "outcome": str(_get(result, "outcome")),
        "certificate": kind,
        "h": np.zeros((0, 0)) if h is None else float(h),
    })
    perf = _get(result, "performance")
    if perf is not None:  # docs/design.md §8: the certified bracket and its certificate
        perf = perf if isinstance(perf, dict) else perf.to_dict()
        nan = float("nan")
        out.update({
            "perf_kind": str(perf["kind"]),
            "perf_upper": nan if perf.get("upper") is None else float(perf["upper"]),
            "perf_lower": nan if perf.get("lower") is None else float(perf["lower"]),
            "P_perf": np.zeros((0, 0)) if perf.get("certificate") is None else np.asarray(perf["certificate"], float),
        })
        if perf.get("mode_certificate") is not None:  # hinf: one storage per loop mode; cost: per next modes
            out["P_perf_modes"] = np.moveaxis(np.asarray(perf["mode_certificate"], float), 0, -1)
    X_inv = _get(result, "invariant_set")
    if X_inv is not None:  # inputs within u_max from every x with x' X_inv x <= 1
        out["X_inv"] = np.asarray(X_inv, dtype=float)
    L = _get(result, "observer_gains")
    if L is not None:  # output feedback: the observer and the whole loop's certificate
        out["L"] = np.moveaxis(np.asarray(L, dtype=float), 0, -1)
        C = family.C if family is not None and family.C is not None else None
        if C is not None:
            out["C"] = np.moveaxis(np.asarray(C, dtype=float), 0, -1)
        joint = _get(result, "joint_certificate")
        if joint is not None:
            joint = joint if isinstance(joint, dict) else joint.to_dict()
            out["P_joint"] = np.asarray(joint["P"], dtype=float)
            out["Q_joint"] = np.moveaxis(np.asarray(joint["Q"], dtype=float), 0, -1)
    network = _get(result, "network")
    if network is not None:  # the certificate holds for this network only: say which
        from .networks import check_network

        net = check_network(network)
        out["network"] = net.describe()
        cert = _get(result, "certificate")
        cert = cert if isinstance(cert, dict) or cert is None else cert.to_dict()
        nodes = list(range(net.nodes))
        if cert and cert.get("nodes"):
            nodes = [int(v) for v in cert["nodes"]]
        elif cert and cert.get("states"):
            nodes = [int(s["node"]) for s in cert["states"]]
            out["P_plant"] = np.asarray([int(s["plant"]) + 1 for s in cert["states"]], dtype=float).reshape(-1, 1)
        out["P_node"] = np.asarray(nodes, dtype=float).reshape(-1, 1) + 1
        out["node_ages"] = np.asarray(net.ages, dtype=float)[nodes].reshape(-1, 1)
    return out


def save_mat(file, result, family: PlantFamily | None = None) -> None:
    """Write the design as a MATLAB 5 ``.mat`` file (``scipy.io.savemat``) to a path or binary file."""
    import scipy.io

    scipy.io.savemat(file, matlab_variables(result, family), do_compression=True, oned_as="column")


def mat_bytes(result, family: PlantFamily | None = None) -> bytes:
    """The ``.mat`` file's bytes (for an HTTP response)."""
    buf = io.BytesIO()
    save_mat(buf, result, family)
    return buf.getvalue()


def _literal(value) -> str:
    """An exact MATLAB/Octave literal: ``%.17g`` floats round-trip bit for bit."""
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return _number(float(arr))
    if arr.size == 0:
        return "[]"
    if arr.ndim == 2:
        return "[" + "; ".join(" ".join(_number(v) for v in row) for row in arr) + "]"
    flat = " ".join(_number(v) for v in arr.flatten(order="F"))
    return f"reshape([{flat}], [{' '.join(str(d) for d in arr.shape)}])"


def _number(v: float) -> str:
    if np.isnan(v):
        return "NaN"
    if np.isinf(v):
        return "Inf" if v > 0 else "-Inf"
    return f"{v:.17g}"


def m_script(result, family: PlantFamily | None = None, name: str | None = None) -> str:
    """An Octave/MATLAB script that defines the design's variables (run it, or ``run('gains.m')``).

    Parameters
    ----------
    result, family
        As for :func:`matlab_variables`.
    name : str, optional
        Shown in the header comment (e.g. the job id).
    """
    variables = matlab_variables(result, family)
    K = variables["K"]
    lines = [
        f"% ncs-design controller{' ' + name if name else ''}: outcome {variables['outcome']}, "
        f"n_drop = {int(variables['n_drop'])}" + (f", network {variables['network']}" if "network" in variables
                                                  else ""),
        "% K(q,:,:) = K_q (n_drop x m x n); Kq the same one by one; the buffer plays u(i_m+q-1) = Kq * x(i_m).",
        "% F(:,:,l), G(:,:,l): plant mode l; P: the Lyapunov certificate (see docs/design.md); h in seconds.",
        f"% sizes: n = {K.shape[2]} states, m = {K.shape[1]} inputs, r = {variables['F'].shape[2]} plant modes",
    ]
    for key, value in variables.items():
        lines.append(f"{key} = {_literal(value)};")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------ input
def _modes(key: str, value, square: bool) -> list[np.ndarray]:
    """One matrix per mode from a loadmat value: cell array, n x k x r array or one 2-D matrix."""
    if isinstance(value, np.ndarray) and value.dtype == object:  # cell array {M1, M2, ...}
        cells = [np.asarray(c, dtype=float) for c in value.ravel(order="F")]
        if not cells:
            raise InvalidInput(f"{key} is an empty cell array", (key,))
        return cells
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInput(f"{key} is not numeric", (key,)) from None
    if arr.ndim == 2:
        return [arr]
    if arr.ndim == 3:
        if square and arr.shape[0] != arr.shape[1]:
            raise InvalidInput(f"{key} has size {'x'.join(map(str, arr.shape))}: a 3-D {key} must be n x n x r "
                               f"({key}(:,:,l) is mode l)", (key,))
        return [arr[:, :, l] for l in range(arr.shape[2])]
    raise InvalidInput(f"{key} must be a matrix, an n x k x r array or a cell array, got {arr.ndim}-D", (key,))


def plant_from_mat(file, sampling_period: float | None = None) -> PlantFamily:
    """A plant family from a ``.mat`` file with ``A``/``B`` (continuous) or ``F``/``G`` (discrete).

    Parameters
    ----------
    file : str, path or binary file
    sampling_period : float, optional
        h in seconds; overrides ``h``/``sampling_period`` in the file.  Required for ``A``/``B``
        unless the file has it.

    Returns
    -------
    PlantFamily

    Raises
    ------
    InvalidInput
        Naming the variable that is missing or malformed.
    """
    import scipy.io

    try:
        data = scipy.io.loadmat(file, squeeze_me=False)
    except Exception as exc:  # scipy raises ValueError, TypeError, MatReadError... for a non-.mat file
        raise InvalidInput(f"not a readable .mat file: {exc}", ("file",)) from None
    h = sampling_period
    if h is None:
        for key in ("sampling_period", "h", "Ts"):
            if key in data and np.size(data[key]) == 1:
                h = float(np.asarray(data[key], dtype=float).ravel()[0])
                break
    label = os.path.splitext(os.path.basename(str(file)))[0] if isinstance(file, (str, os.PathLike)) else None
    if "A" in data and "B" in data:
        if h is None:
            raise InvalidInput("a continuous plant (A, B) needs a sampling period: store h in the file or "
                               "give --sampling-period", ("sampling_period",))
        return PlantFamily.from_continuous(_modes("A", data["A"], True), _modes("B", data["B"], False), h,
                                           name=label)
    if "F" in data and "G" in data:
        return PlantFamily(F=_modes("F", data["F"], True), G=_modes("G", data["G"], False),
                           sampling_period=h, name=label)
    found = sorted(k for k in data if not k.startswith("__"))
    raise InvalidInput(f"the .mat file needs A and B (continuous) or F and G (discrete); it has {found}",
                       ("file",))
