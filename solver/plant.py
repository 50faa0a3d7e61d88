"""Switched plant families ``x(k+1) = F_l x(k) + G_l u(k)``, l = 1..r (eq. 1).

A family is stored in discrete time.  Continuous families (eq. 2) are
discretized by the exact zero-order hold of eq. 3::

    expm([[A, B], [0, 0]] * h) = [[F, G], [0, I]]
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.linalg

from .errors import InvalidInput

# Eq. 19 of the paper (the matrices its eq. 20 and its results are built on).
# Table I's parameters give a different A for J = 0.03 (see docs/methods.md): the paper
# example reproduces the paper, the DC motor builder follows the physics.
_PAPER_A = (
    [[-4.0, -0.03], [0.5, -6.667]],
    [[-4.0, -0.03], [0.75, -10.0]],
    [[-4.0, -0.03], [1.5, -20.0]],
)
_PAPER_B = ([[2.0], [0.0]],) * 3

#: Names and units of the DC motor's state ``x = [i_a, omega]`` and input (eq. 16/18).
DC_MOTOR_LABELS = {
    "state_names": ("i_a", "omega"),
    "input_names": ("v_a",),
    "units": {"i_a": "A", "omega": "rad/s", "v_a": "V"},
}


def _matrix_list(name: str, mats, ndim_cols: int | None = None) -> list[np.ndarray]:
    """Convert a list of matrices to float64 arrays, naming the bad one on error."""
    if _is_single_matrix(mats, strict=ndim_cols is None):
        raise InvalidInput(
            f"{name} must be a list of matrices, one per plant mode, but got a single matrix; "
            f"for a plant with one mode wrap it in a list: {name}=[{name}]", (name,))
    if isinstance(mats, np.ndarray):
        mats = list(mats)
    if not isinstance(mats, (list, tuple)) or len(mats) == 0:
        raise InvalidInput(f"{name} must be a non-empty list of matrices, one per plant mode", (name,))
    out = []
    for i, mat in enumerate(mats):
        try:
            arr = np.array(mat, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidInput(f"{name}[{i}] is not a numeric matrix", (name, i)) from None
        if arr.ndim == 1 and ndim_cols == 1:
            arr = arr.reshape(-1, 1)
        if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
            raise InvalidInput(f"{name}[{i}] must be a non-empty 2-D matrix, got shape {arr.shape}", (name, i))
        if not np.all(np.isfinite(arr)):
            raise InvalidInput(f"{name}[{i}] has NaN or infinite entries", (name, i))
        out.append(arr)
    return out


def _is_single_matrix(mats, strict: bool) -> bool:
    """A 2-D array (or, when ``strict``, a list of rows of numbers) where a list of matrices was expected.

    ``strict`` is False for input matrices, whose modes may be given as 1-D columns (m = 1), so a
    nested list of numbers is ambiguous there.
    """
    if isinstance(mats, np.ndarray):
        return mats.ndim == 2
    if not strict or not isinstance(mats, (list, tuple)) or not mats:
        return False
    return all(isinstance(row, (list, tuple)) and row and
               all(isinstance(v, (int, float, np.number)) and not isinstance(v, bool) for v in row)
               for row in mats)


def _control_characters(text: str) -> bool:
    return any(ord(c) < 0x20 or ord(c) == 0x7F for c in text)


def _check_names(key: str, names, count: int) -> tuple[str, ...] | None:
    if names is None:
        return None
    if isinstance(names, str) or not all(isinstance(v, str) and v for v in names):
        raise InvalidInput(f"{key} must be a list of non-empty strings", (key,))
    names = tuple(names)
    for i, v in enumerate(names):
        if _control_characters(v):  # figures are SVG: XML has no way to hold NUL and most C0 controls
            raise InvalidInput(f"{key}[{i}] contains a control character; use printable text", (key, i))
    if len(names) != count:
        raise InvalidInput(f"{key} has {len(names)} names but the plant has {count}", (key,))
    if len(set(names)) != len(names):
        raise InvalidInput(f"{key} has duplicate names", (key,))
    return names


def _check_family(Fs, Gs, fname: str, gname: str) -> tuple[int, int]:
    if len(Fs) != len(Gs):
        raise InvalidInput(
            f"{fname} has {len(Fs)} modes but {gname} has {len(Gs)}; give one pair per plant mode", (gname,)
        )
    n = Fs[0].shape[0]
    m = Gs[0].shape[1]
    for i, (Fi, Gi) in enumerate(zip(Fs, Gs)):
        if Fi.shape[0] != Fi.shape[1]:
            raise InvalidInput(f"{fname}[{i}] must be square, got shape {Fi.shape}", (fname, i))
        if Fi.shape != (n, n):
            raise InvalidInput(
                f"{fname}[{i}] has shape {Fi.shape} but mode 0 has {(n, n)}: all modes need the same state size",
                (fname, i),
            )
        if Gi.shape[0] != n:
            raise InvalidInput(f"{gname}[{i}] has {Gi.shape[0]} rows but the state size is {n}", (gname, i))
        if Gi.shape[1] != m:
            raise InvalidInput(
                f"{gname}[{i}] has {Gi.shape[1]} columns but mode 0 has {m}: all modes need the same input size",
                (gname, i),
            )
    return n, m


def _check_outputs(C, r: int, n: int) -> np.ndarray:
    """Output matrices as a read-only (r, p, n) array; one (p, n) matrix is repeated for every mode."""
    try:
        arr = np.array(C, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInput("C must be a p x n matrix of numbers (or one per plant mode)", ("C",)) from None
    if arr.ndim == 1 and arr.shape == (n,):
        arr = arr[None]
    if arr.ndim == 2:
        arr = np.repeat(arr[None], r, axis=0)
    if arr.ndim != 3 or arr.shape[0] != r or arr.shape[2] != n or arr.shape[1] < 1:
        raise InvalidInput(f"C must be p x {n} (one matrix, or one per each of the {r} plant modes), "
                           f"got shape {arr.shape}", ("C",))
    if not np.all(np.isfinite(arr)):
        raise InvalidInput("C has NaN or infinite entries", ("C",))
    arr.setflags(write=False)
    return arr


def _check_sampling_period(h) -> float:
    try:
        h = float(h)
    except (TypeError, ValueError):
        raise InvalidInput("sampling_period must be a number (seconds)", ("sampling_period",)) from None
    if not np.isfinite(h) or h <= 0:
        raise InvalidInput(f"sampling_period must be positive and finite, got {h}", ("sampling_period",))
    return h


def zero_order_hold(A: np.ndarray, B: np.ndarray, sampling_period: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretization (eq. 3).

    Parameters
    ----------
    A : ndarray, shape (n, n)
        Continuous state matrix (1/s).
    B : ndarray, shape (n, m)
        Continuous input matrix.
    sampling_period : float
        Sampling period h in seconds.

    Returns
    -------
    F : ndarray, shape (n, n)
        ``expm(A h)``.
    G : ndarray, shape (n, m)
        ``int_0^h expm(A tau) dtau B``.
    """
    n, m = B.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = A
    block[:n, n:] = B
    phi = scipy.linalg.expm(block * sampling_period)
    return phi[:n, :n], phi[:n, n:]


@dataclass(frozen=True, eq=False)
class PlantFamily:
    """A family of r discrete-time linear plants sharing n states and m inputs.

    Parameters
    ----------
    F : sequence of array_like, each (n, n)
        State matrices ``F_l``, one per plant mode.
    G : sequence of array_like, each (n, m)
        Input matrices ``G_l``.
    sampling_period : float, optional
        Sampling period h in seconds; only used to label time axes.
    A, B : ndarray, optional
        Continuous matrices the family was discretized from (kept for reference).
    name : str, optional
        Label used in reports.
    state_names : sequence of str, optional
        One name per state, e.g. ``("i_a", "omega")``; figures and the python-control
        and MATLAB exports use them (default ``x1..xn``).
    input_names : sequence of str, optional
        One name per input (default ``u1..um``).
    units : dict of str to str, optional
        Unit of each named state or input, e.g. ``{"i_a": "A", "omega": "rad/s", "V": "V"}``
        (keys are names from ``state_names``/``input_names``).
    mode_names : sequence of str, optional
        One name per plant mode, e.g. ``("pole 0.2 m", "pole 0.3 m")``; figure titles and the
        plant-mode strip use them (default: the 0-based index).
    C : array_like (p, n) or sequence of them, optional
        Measured outputs ``y = C_l x`` for output feedback (``design(..., feedback="output")``); one
        matrix is used for every mode.

    Attributes
    ----------
    F : ndarray, shape (r, n, n)
    G : ndarray, shape (r, n, m)
    C : ndarray, shape (r, p, n), or None

    Raises
    ------
    InvalidInput
        On non-square or mismatched matrices, non-finite entries, an empty
        family or a non-positive sampling period; ``err.field`` names the
        offending field and mode.
    """

    F: np.ndarray
    G: np.ndarray
    sampling_period: float | None = None
    A: np.ndarray | None = field(default=None, repr=False)
    B: np.ndarray | None = field(default=None, repr=False)
    name: str | None = None
    state_names: tuple[str, ...] | None = None
    input_names: tuple[str, ...] | None = None
    units: dict | None = None
    mode_names: tuple[str, ...] | None = None
    C: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        Fs = _matrix_list("F", self.F)
        Gs = _matrix_list("G", self.G, ndim_cols=1)
        n, m = _check_family(Fs, Gs, "F", "G")
        h = None if self.sampling_period is None else _check_sampling_period(self.sampling_period)
        state_names = _check_names("state_names", self.state_names, n)
        input_names = _check_names("input_names", self.input_names, m)
        units = None
        if self.units is not None:
            if not isinstance(self.units, dict) or not all(
                    isinstance(k, str) and isinstance(v, str) for k, v in self.units.items()):
                raise InvalidInput("units must map state or input names to unit strings, e.g. "
                                   '{"omega": "rad/s"}', ("units",))
            for k, v in self.units.items():
                if _control_characters(k) or _control_characters(v):
                    raise InvalidInput(f"units[{k!r}] contains a control character; use printable text",
                                       ("units", k))
            known = set(state_names or ()) | set(input_names or ())
            unknown = sorted(set(self.units) - known)
            if unknown:
                raise InvalidInput(f"units names {unknown} that are not in state_names or input_names",
                                   ("units", unknown[0]))
            units = dict(self.units)
        object.__setattr__(self, "mode_names", _check_names("mode_names", self.mode_names, len(Fs)))
        object.__setattr__(self, "state_names", state_names)
        object.__setattr__(self, "input_names", input_names)
        object.__setattr__(self, "units", units)
        F = np.stack(Fs)
        G = np.stack(Gs)
        F.setflags(write=False)
        G.setflags(write=False)
        object.__setattr__(self, "F", F)
        object.__setattr__(self, "G", G)
        object.__setattr__(self, "sampling_period", h)
        if self.C is not None:
            object.__setattr__(self, "C", _check_outputs(self.C, len(Fs), n))

    # ------------------------------------------------------------------ builders
    @classmethod
    def from_continuous(cls, A: Sequence, B: Sequence, sampling_period: float, name: str | None = None,
                        C=None, **labels) -> "PlantFamily":
        """Discretize a continuous family ``dx/dt = A_l x + B_l u`` by zero-order hold (eq. 3).

        Parameters
        ----------
        A : sequence of array_like, each (n, n)
            Continuous state matrices (1/s).
        B : sequence of array_like, each (n, m)
            Continuous input matrices.
        sampling_period : float
            Sampling period h in seconds, > 0.
        name : str, optional
        C : array_like, optional
            Measured outputs ``y = C x`` (kept as they are: sampling does not change them).
        **labels
            ``state_names``, ``input_names``, ``units`` (see :class:`PlantFamily`).
        """
        As = _matrix_list("A", A)
        Bs = _matrix_list("B", B, ndim_cols=1)
        _check_family(As, Bs, "A", "B")
        h = _check_sampling_period(sampling_period)
        pairs = [zero_order_hold(Ai, Bi, h) for Ai, Bi in zip(As, Bs)]
        for i, (Fi, Gi) in enumerate(pairs):
            if not (np.all(np.isfinite(Fi)) and np.all(np.isfinite(Gi))):
                raise InvalidInput(f"A[{i}] overflows when discretized at h = {h}", ("A", i))
        return cls(
            F=[p[0] for p in pairs],
            G=[p[1] for p in pairs],
            sampling_period=h,
            A=np.stack(As),
            B=np.stack(Bs),
            name=name,
            C=C,
            **labels,
        )

    @classmethod
    def from_dict(cls, data: dict, sampling_period: float | None = None) -> "PlantFamily":
        """A family from the service's plant JSON (the ``plant`` of a design request).

        Parameters
        ----------
        data : dict
            ``{"kind": "continuous", "A": [...], "B": [...], "sampling_period": h}``,
            ``{"kind": "discrete", "F": [...], "G": [...]}`` or
            ``{"kind": "dc_motor", "inertias": [...], "sampling_period": h, ...}``; optional
            ``state_names``, ``input_names``, ``units``, ``name``.  Without ``kind``, ``A``/``B``
            means continuous and ``F``/``G`` discrete.
        sampling_period : float, optional
            h in seconds, overriding the one in ``data``.

        Raises
        ------
        InvalidInput
            Naming the missing or malformed key.
        """
        if not isinstance(data, dict):
            raise InvalidInput("a plant must be a JSON object with a \"kind\"", ("plant",))
        kind = data.get("kind") or ("continuous" if "A" in data else "discrete" if "F" in data else None)
        h = data.get("sampling_period") if sampling_period is None else sampling_period
        labels = {k: data[k] for k in ("state_names", "input_names", "units", "name", "mode_names", "C")
                  if data.get(k) is not None}
        need = {"continuous": ("A", "B", "sampling_period"), "discrete": ("F", "G"),
                "dc_motor": ("inertias", "sampling_period")}
        if kind not in need:
            raise InvalidInput(f"plant kind must be one of {sorted(need)}, got {kind!r}", ("kind",))
        for key in need[kind]:
            if (h if key == "sampling_period" else data.get(key)) is None:
                raise InvalidInput(f"a {kind} plant needs {key!r}", (key,))
        if kind == "continuous":
            return cls.from_continuous(data["A"], data["B"], h, **labels)
        if kind == "discrete":
            return cls(F=data["F"], G=data["G"], sampling_period=h, **labels)
        params = {k: data[k] for k in ("resistance", "inductance", "torque_constant", "back_emf_constant",
                                       "damping") if data.get(k) is not None}
        fam = cls.dc_motor(data["inertias"], h, **params)
        if labels:
            fam = cls(F=fam.F, G=fam.G, sampling_period=fam.sampling_period, A=fam.A, B=fam.B,
                      **{"name": fam.name, "mode_names": fam.mode_names, **DC_MOTOR_LABELS, **labels})
        return fam

    @classmethod
    def from_statespace(cls, systems, sampling_period: float | None = None, name: str | None = None,
                        units: dict | None = None) -> "PlantFamily":
        """A family from python-control ``StateSpace`` systems, one per plant mode.

        Only ``A`` and ``B`` are used (the controllers are state feedback); ``C`` and ``D`` are ignored.
        State and input names are kept unless they are python-control's defaults (``x[0]``, ``u[0]``).

        Parameters
        ----------
        systems : sequence of control.StateSpace (or one StateSpace for a single mode)
            All continuous (``dt = 0``) or all discrete, with the same numbers of states and inputs.
        sampling_period : float, optional
            h in seconds.  Continuous systems are discretized by zero-order hold at h (required);
            discrete systems use their ``dt``, and h, when given, must agree with it
            (``dt=True``, python-control's "unspecified", takes h or stays unlabelled).
        name : str, optional
            Label used in reports (default: the first system's name when it is not python-control's default).
        units : dict of str to str, optional
            Unit of each named state or input.

        Returns
        -------
        PlantFamily
            Continuous input keeps ``A`` and ``B`` for reference.

        Raises
        ------
        InvalidInput
            On a non-StateSpace entry (``field = ("systems", i)``), mixed continuous and discrete
            systems, disagreeing sampling periods or names, or a missing sampling period.

        Examples
        --------
        >>> import control as ct
        >>> motor = [ct.ss([[-4, -0.3], [5, -J]], [[2], [0]], [[0, 1]], 0, states=["i_a", "omega"])
        ...          for J in (6.7, 10.0)]
        >>> fam = PlantFamily.from_statespace(motor, sampling_period=0.1)
        >>> fam.state_names
        ('i_a', 'omega')
        """
        systems = [systems] if _is_statespace(systems) else systems
        if not isinstance(systems, (list, tuple)) or not systems:
            raise InvalidInput("systems must be a non-empty list of control.StateSpace, one per plant mode",
                               ("systems",))
        for i, sys in enumerate(systems):
            if not _is_statespace(sys):
                raise InvalidInput(f"systems[{i}] is a {type(sys).__name__}, not a control.StateSpace "
                                   "(convert transfer functions with control.ss)", ("systems", i))
        continuous = [bool(sys.isctime(strict=True)) for sys in systems]
        if any(continuous) and not all(continuous):
            i = continuous.index(not continuous[0])
            raise InvalidInput(f"systems[{i}] is {'continuous' if continuous[i] else 'discrete'} but systems[0] "
                               "is not: give all modes in the same time domain", ("systems", i))
        labels = {"units": units, "name": name or _custom_name(systems[0])}
        for key, attr, default in (("state_names", "state_labels", "x"), ("input_names", "input_labels", "u")):
            names = [tuple(getattr(sys, attr)) for sys in systems]
            for i, got in enumerate(names):
                if got != names[0]:
                    raise InvalidInput(f"systems[{i}] names its {key.split('_')[0]}s {list(got)} but systems[0] "
                                       f"names them {list(names[0])}", ("systems", i))
            custom = not all(label == f"{default}[{j}]" for j, label in enumerate(names[0]))
            labels[key] = names[0] if custom else None
        A = [np.asarray(sys.A, dtype=float) for sys in systems]
        B = [np.asarray(sys.B, dtype=float) for sys in systems]
        if continuous[0]:
            if sampling_period is None:
                raise InvalidInput("sampling_period is required to discretize continuous systems (zero-order hold)",
                                   ("sampling_period",))
            return cls.from_continuous(A, B, sampling_period, **labels)
        dts = [sys.dt for sys in systems]
        given = [float(dt) for dt in dts if dt is not True and dt is not None]
        h = None if sampling_period is None else _check_sampling_period(sampling_period)
        for i, dt in enumerate(dts):
            if dt is True or dt is None:
                continue
            ref = h if h is not None else given[0]
            if not np.isclose(float(dt), ref, rtol=1e-9, atol=0.0):
                what = f"sampling_period={h}" if h is not None else f"systems[0].dt={given[0]}"
                raise InvalidInput(f"systems[{i}].dt = {float(dt)} s disagrees with {what}: all modes need "
                                   "the same sampling period", ("systems", i))
        return cls(F=A, G=B, sampling_period=h if h is not None else (given[0] if given else None), **labels)

    @classmethod
    def dc_motor(
        cls,
        inertias: Sequence[float],
        sampling_period: float,
        resistance: float = 2.0,
        inductance: float = 0.5,
        torque_constant: float = 0.15,
        back_emf_constant: float = 0.15,
        damping: float = 0.2,
    ) -> "PlantFamily":
        """DC motor with switching inertia, from the physics of eq. 16/18.

        State ``x = [i_a, omega]`` (A, rad/s), input armature voltage (V)::

            A = [[-R/L, -Kb/L], [Km/J, -B/J]],   B = [[1/L], [0]]

        Parameters
        ----------
        inertias : sequence of float
            Moment of inertia J of each plant mode (kg m^2), > 0.
        sampling_period : float
            h in seconds.
        resistance, inductance, torque_constant, back_emf_constant, damping : float
            R (ohm), L (H), Km (N m/A), Kb (V s/rad), B (N m s/rad); defaults are Table I.

        Notes
        -----
        With Table I's values this gives ``A = [[-4, -0.3], [5, -6.667]]`` for
        J = 0.03, not eq. 19's ``[[-4, -0.03], [0.5, -6.667]]``; use
        :meth:`paper_example` to reproduce the paper's numbers.
        """
        params = {
            "resistance": resistance,
            "inductance": inductance,
            "torque_constant": torque_constant,
            "back_emf_constant": back_emf_constant,
            "damping": damping,
        }
        for key, value in params.items():
            try:
                ok = np.isfinite(float(value))
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise InvalidInput(f"{key} must be a finite number", (key,))
        if float(inductance) <= 0:
            raise InvalidInput("inductance must be positive", ("inductance",))
        try:
            Js = [float(J) for J in inertias]
        except (TypeError, ValueError):
            raise InvalidInput("inertias must be a list of numbers", ("inertias",)) from None
        if not Js:
            raise InvalidInput("inertias must list at least one inertia", ("inertias",))
        for i, J in enumerate(Js):
            if not np.isfinite(J) or J <= 0:
                raise InvalidInput(f"inertias[{i}] must be positive, got {J}", ("inertias", i))
        R, L, Km, Kb, Bd = (float(v) for v in params.values())
        A = [[[-R / L, -Kb / L], [Km / J, -Bd / J]] for J in Js]
        B = [[[1.0 / L], [0.0]] for _ in Js]
        names = [f"J = {J:g} kg m^2" for J in Js]
        return cls.from_continuous(A, B, sampling_period, name="dc_motor", **DC_MOTOR_LABELS,
                                   mode_names=names if len(set(names)) == len(names) else None)

    @classmethod
    def paper_example(cls, sampling_period: float = 0.1) -> "PlantFamily":
        """The paper's switched DC motor, eq. 19 (three inertias), discretized at h."""
        return cls.from_continuous(_PAPER_A, _PAPER_B, sampling_period, name="paper_example", **DC_MOTOR_LABELS)

    # ---------------------------------------------------------------- properties
    @property
    def n_modes(self) -> int:
        """Number r of plant modes."""
        return self.F.shape[0]

    @property
    def n_states(self) -> int:
        """State dimension n."""
        return self.F.shape[1]

    @property
    def n_inputs(self) -> int:
        """Input dimension m."""
        return self.G.shape[2]

    def state_label(self, i: int) -> str:
        """Axis label of state i (0-based): its name and unit, e.g. ``"omega (rad/s)"``, else ``"x1"``."""
        return self._label(self.state_names, "x", i)

    def input_label(self, j: int) -> str:
        """Axis label of input j (0-based), e.g. ``"v_a (V)"``, else ``"u1"``."""
        return self._label(self.input_names, "u", j)

    def _label(self, names, prefix: str, i: int) -> str:
        if names is None:
            return f"{prefix}{i + 1}"
        unit = (self.units or {}).get(names[i])
        return f"{names[i]} ({unit})" if unit else names[i]

    def to_dict(self) -> dict:
        """JSON-able description (discrete matrices, and continuous ones when known)."""
        out = {
            "n_modes": self.n_modes,
            "n_states": self.n_states,
            "n_inputs": self.n_inputs,
            "sampling_period": self.sampling_period,
            "F": self.F.tolist(),
            "G": self.G.tolist(),
        }
        if self.A is not None:
            out["A"] = self.A.tolist()
            out["B"] = self.B.tolist()
        for key in ("state_names", "input_names"):
            if getattr(self, key) is not None:
                out[key] = list(getattr(self, key))
        if self.units is not None:
            out["units"] = dict(self.units)
        if self.C is not None:
            out["C"] = self.C.tolist()
        return out


def _is_statespace(obj) -> bool:
    """A python-control StateSpace (checked by duck type: python-control stays an optional import)."""
    return all(hasattr(obj, attr) for attr in ("A", "B", "dt", "state_labels", "input_labels", "isctime"))


def _custom_name(sys) -> str | None:
    name = getattr(sys, "name", None)
    return None if not name or name.startswith("sys[") else name
