"""The error model's effects (docs/format.md, parameter names): each a small class that knows its
parameters, the measured columns it needs, how it perturbs the joint angles or the chain, and its
analytic columns of the identification Jacobian.

Two kinds:

* :class:`JointAngleEffect`: ``theta_i = q_i + sum_k p_k * basis_k(inputs)``, linear in its
  parameters, evaluated at the encoder reading q (first order). A subclass names its ``terms`` and
  gives ``basis(inputs, joint, term)``; parameters are ``f"{term}{joint}"`` (``ts1``, ``c3``...).
* :class:`ChainEffect`: changes the chain itself (geometric errors, thermal growth). A subclass
  implements ``apply`` and, for speed, ``jacobian``; without it the model differentiates
  numerically.

A user's effect is one such class in a Python file, loaded by ``--effect-module FILE.py`` (every
:class:`Effect` subclass with a ``name`` in the file is registered) or from another package through
the ``sixaxis.effects`` entry-point group.

It is one module, longer than most, because the effect base classes, the catalogue built on them and
the registry that finds a user's effects (``--effect-module``, entry points) are one plug-in
interface.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import importlib.util
import inspect
import logging
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from arm.description import RobotDescription, seed_robot
from arm.effect_api import ChainState, EffectError, ModelInputs, Sensitivities
from arm.errors import SixAxisError
from arm.files import check_input_file
from arm.params import BASE_NAMES, TOOL_ROTATION_NAMES, parse_parameter_name
from arm.so3 import rotation_matrix

__all__ = [
    "EFFECTS",
    "FAST_PARTS",
    "PLAUSIBLE_FACTOR",
    "Backlash",
    "ChainEffect",
    "Compliance",
    "Cyclic",
    "Effect",
    "Geometric",
    "JointAngleEffect",
    "JointScale",
    "LoadBacklash",
    "Thermal",
    "Transmission",
    "candidate_effects",
    "check_robot_effects",
    "cyclic_readings",
    "effect_origin",
    "is_catalogued",
    "load_effect_module",
    "make_effect",
    "missing_inputs",
    "order_reading",
    "parse_effects",
    "register_effect",
    "user_code",
    "user_module_failure",
]

log = logging.getLogger(__name__)

REFERENCE_TEMPERATURE = 20.0  # degC, where thermal growth is zero
# An identified parameter is implausible beyond this many times the top of its typical range:
# a compliance ten times that of a soft harmonic drive, a gap of 20 arcmin, kappa of 2.3e-4/K
# (ten times aluminium's) come from the data's units or another robot, not from the arm.
PLAUSIBLE_FACTOR = 10.0
#: the largest value a basis (a joint-angle regressor) may take: far from overflow when squared,
#: as the readers' bound on any other column (arm.ranges.MAX_EXTRA)
MAX_BASIS = 1e12


_SOURCES: dict[type, str] = {}  # the file each --effect-module class was loaded from


def effect_origin(effect: Effect | type[Effect]) -> str:
    """``effect 'mine' (module /path/mine.py)``: the effect and the file that defines it, as an
    error names them."""
    cls = effect if isinstance(effect, type) else type(effect)
    where = _SOURCES.get(cls)
    if where is None:
        try:
            where = inspect.getsourcefile(cls) or cls.__module__
        except TypeError:
            where = cls.__module__
    return f"effect {cls.name!r} (module {where})"


def is_catalogued(effect: Effect | type[Effect]) -> bool:
    """Whether ``effect`` is one of the catalogue's own (defined in this module)."""
    cls = effect if isinstance(effect, type) else type(effect)
    return cls.__module__ == __name__


@contextlib.contextmanager
def user_code(effect: Effect | type[Effect], what: str) -> Iterator[None]:
    """Run a user effect's code: an exception it raises (a ``ZeroDivisionError``, a
    ``KeyError``, even ``SystemExit``) becomes one :class:`EffectError` naming the module, the
    effect and what it was doing. The catalogue's own failures are bugs and keep their
    traceback; the project's own errors pass as they are."""
    try:
        yield
    except SixAxisError:
        raise
    except (Exception, SystemExit) as exc:
        if is_catalogued(effect):
            raise
        raise EffectError(
            f"{effect_origin(effect)}: {what} raised {type(exc).__name__}: {exc}"
        ) from None


class Effect:
    """Base of all effects. Subclasses set ``name`` and implement one of the two kinds below."""

    name: ClassVar[str] = ""
    columns: ClassVar[tuple[str, ...]] = ()  # measured columns it needs (beyond q, x, y, z)
    per_joint: ClassVar[bool] = False
    description: ClassVar[str] = ""
    # Typical magnitude range of each parameter family (name prefix; docs/format.md, parameter
    # names), and whether its sign is physical (always positive) rather than either way.
    typical: ClassVar[dict[str, tuple[float, float]]] = {}
    positive: ClassVar[bool] = False
    # What the effect cannot be fitted without, besides ``columns``: the arm's mass model (an
    # effect driven by gravity torques; without masses they are zero and it moves nothing).
    needs_masses: ClassVar[bool] = False
    # The largest plausible magnitude of each parameter family (name prefix), SI units; None
    # exempts a family. A family without one is bounded by PLAUSIBLE_FACTOR times the top of its
    # typical range; an identified value beyond its bound is an error (units, another robot,
    # another convention) unless the user accepts it (lab.plausibility).
    bounds: ClassVar[dict[str, float | None]] = {}
    # An effect whose terms a scan finds (its joints and orders), rather than one the diagnosis
    # tests whole: it has no meaning without its brackets, and the catalogue's tests skip it.
    scan_only: ClassVar[bool] = False
    # A specification that names the effect fully (what the documentation and tests build).
    example: ClassVar[str] = ""
    # Whether its form is a law of the arm over its whole range (a joint's stiffness, backlash):
    # then it holds outside the poses it was fitted on. Otherwise its terms are used
    # outside the fitted range of what they depend on only where their form repeats over a
    # range the fit covered (a harmonic of a joint angle); lab.domain.
    extrapolates: ClassVar[bool] = False

    def __init__(self, joints: Sequence[int] | None = None) -> None:
        if joints is not None and not self.per_joint:
            raise EffectError(f"effect {self.name!r} is not per joint; it takes no joint list")
        self.joints: tuple[int, ...] | None = None if joints is None else tuple(sorted(set(joints)))
        if self.joints == ():
            raise EffectError(
                f"effect {self.name!r}: an empty joint list; name the joints "
                f"({self.name}[2,3]) or leave out the brackets for all of them"
            )
        if self.joints is not None and any(not 1 <= j <= 6 for j in self.joints):
            raise EffectError(
                f"effect {self.name!r}: joints must be within 1..6, got {self.joints}"
            )

    @classmethod
    def from_spec(cls, brackets: str | None, spec: str = "") -> Effect:
        """The effect from the text between its brackets (None: no brackets): a joint list,
        ``2,3``. ``spec`` is the whole specification, for the messages."""
        if brackets is None:
            return cls()
        try:
            js = [int(j) for j in brackets.split(",") if j.strip()]
        except ValueError:
            raise EffectError(
                f"bad joint list in effect specification {spec!r}; expected e.g. '{cls.name}[2,3]'"
            ) from None
        if not js:
            raise EffectError(
                f"effect specification {spec!r} has an empty joint list; name the joints "
                f"({cls.name}[2,3]) or leave out the brackets for all of them"
            )
        return cls(joints=js)

    @classmethod
    def from_parameters(cls, names: Sequence[str]) -> Effect:
        """The effect that has (at least) the parameters ``names``: what a calibrated arm's
        ``[effects.NAME]`` values need (all joints, unless the effect's terms are named)."""
        return cls()

    @property
    def label(self) -> str:
        """``compliance`` or, restricted to joints, ``compliance[2,3]``."""
        if self.joints is None:
            return self.name
        return f"{self.name}[{','.join(map(str, self.joints))}]"

    def parameter_names(self, robot: RobotDescription, targets: Sequence[int]) -> list[str]:
        """Names of the parameters; ``targets`` are the ids of the measured tool points."""
        raise NotImplementedError

    def typical_range(self, name: str) -> tuple[float, float] | None:
        """The typical magnitude range of parameter ``name`` (by the longest prefix of
        :attr:`typical` it starts with), or None where the effect states none."""
        for prefix in sorted(self.typical, key=len, reverse=True):
            if name.startswith(prefix):
                return self.typical[prefix]
        return None

    def plausible_bound(self, name: str) -> float | None:
        """The largest plausible magnitude of parameter ``name`` (SI): from :attr:`bounds` by
        the longest prefix, else :data:`PLAUSIBLE_FACTOR` times the top of its typical range;
        None where the effect states neither, or exempts the family."""
        for prefix in sorted(self.bounds, key=len, reverse=True):
            if name.startswith(prefix):
                return self.bounds[prefix]
        rg = self.typical_range(name)
        return None if rg is None else PLAUSIBLE_FACTOR * rg[1]

    def ambiguity_note(self, inputs: ModelInputs, i: int) -> str | None:
        """Why this effect's law cannot say how pose ``i`` is affected (a load-dependent
        effect at zero load), or None: a pose that misses there is explained, not suspect."""
        return None

    def nominal(self, robot: RobotDescription, names: Sequence[str]) -> np.ndarray:
        """Starting values: those the description carries for this effect, else zero."""
        known = robot.effects.get(self.name, {})
        return np.array([known.get(n, 0.0) for n in names], dtype=float)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.label!r})"


# --------------------------------------------------------------------------------------------------
class JointAngleEffect(Effect):
    """``theta_i = q_i + sum_term p[term, i] * basis(inputs, i, term)`` for each joint i."""

    per_joint = True
    terms: ClassVar[tuple[str, ...]] = ()

    def active_joints(self) -> tuple[int, ...]:
        return self.joints if self.joints is not None else (1, 2, 3, 4, 5, 6)

    def parameter_terms(self) -> list[tuple[int, str]]:
        """(joint, term) of each parameter, in the order of :meth:`parameter_names`."""
        return [(j, t) for t in self.terms for j in self.active_joints()]

    def parameter_names(self, robot: RobotDescription, targets: Sequence[int]) -> list[str]:
        return [f"{t}{j}" for j, t in self.parameter_terms()]

    def basis(self, inputs: ModelInputs, joint: int, term: str) -> np.ndarray:
        """(N,) regressor of parameter ``{term}{joint}`` on theta_joint (``joint`` is 1-based)."""
        raise NotImplementedError

    def checked_basis(self, inputs: ModelInputs, joint: int, term: str) -> np.ndarray:
        """:meth:`basis` as an (N,) array of finite numbers; anything else it returns, and any
        exception it raises, is an :class:`EffectError` naming the module, the effect, the term
        and the joint (a user's basis is the user's code: its failure is one line)."""
        what = f"basis(joint {joint}, term {term!r})"
        with user_code(self, what):
            value = self.basis(inputs, joint, term)
        if np.iscomplexobj(value):
            raise EffectError(f"{effect_origin(self)}: {what} returned complex numbers")
        try:
            b = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            b = None
        if b is None or b.shape != (inputs.n,):
            got = (
                repr(value)[:40]
                if b is None or value is None or isinstance(value, str)
                else ("a scalar" if b.ndim == 0 else f"shape {b.shape}")
            )
            raise EffectError(
                f"{effect_origin(self)}: {what} returned {got}, not one number per pose "
                f"(shape ({inputs.n},))"
            )
        bad = np.flatnonzero(~np.isfinite(b))
        if bad.size:
            raise EffectError(
                f"{effect_origin(self)}: {what} returned {b[bad[0]]} at pose {bad[0] + 1} "
                f"({bad.size} of {inputs.n} poses not finite)"
            )
        huge = np.flatnonzero(np.abs(b) > MAX_BASIS)
        if huge.size:
            raise EffectError(
                f"{effect_origin(self)}: {what} returned {b[huge[0]]:g} at pose {huge[0] + 1}, "
                f"beyond {MAX_BASIS:g} (a regressor must stay far from overflow when squared)"
            )
        return b

    def regressor(self, inputs: ModelInputs) -> np.ndarray:
        """(N, 6, k): d theta / d parameters, in the order of :meth:`parameter_names`."""
        terms = self.parameter_terms()
        out = np.zeros((inputs.n, 6, len(terms)))
        for k, (j, t) in enumerate(terms):
            out[:, j - 1, k] = self.checked_basis(inputs, j, t)
        return out

    def joint_offsets(self, inputs: ModelInputs, values: np.ndarray) -> np.ndarray:
        """(N, 6) change of the joint angles."""
        if type(self).regressor is not JointAngleEffect.regressor:  # a subclass's own regressor
            return inputs.cached(self, self.regressor) @ values
        joints, basis = inputs.cached(self, self._sparse_regressor)
        out = np.zeros((6, inputs.n))
        if type(self).parameter_terms is not JointAngleEffect.parameter_terms:
            np.add.at(out, joints, basis * values[:, None])  # a joint may have several terms
            return out.T
        m = len(self.active_joints())
        for t in range(len(self.terms)):  # within a term the joints are distinct
            sl = slice(t * m, (t + 1) * m)
            out[joints[sl]] += basis[sl] * values[sl, None]
        return out.T

    def joint_jacobian(self, inputs: ModelInputs, values: np.ndarray) -> np.ndarray:
        """(N, 6, k) d theta / d values; the regressor itself for a linear effect."""
        return inputs.cached(self, self.regressor)

    def _sparse_regressor(self, inputs: ModelInputs) -> tuple[np.ndarray, np.ndarray]:
        """The regressor's one non-zero per parameter: its joint (k,) and values (k, N)."""
        terms = self.parameter_terms()
        joints = np.array([j - 1 for j, _ in terms], dtype=int)
        basis = np.array([self.checked_basis(inputs, j, t) for j, t in terms], dtype=float)
        return joints, basis.reshape(len(joints), inputs.n)

    def jacobian_into(
        self, inputs: ModelInputs, values: np.ndarray, sens: Sensitivities, out: np.ndarray
    ) -> bool:
        """Write d point / d values, component-major (k, 3, N), into ``out``."""
        cls = type(self)
        if (
            cls.regressor is JointAngleEffect.regressor
            and cls.joint_jacobian is JointAngleEffect.joint_jacobian
        ):  # linear, one joint per parameter: a gather and a product
            joints, basis = inputs.cached(self, self._sparse_regressor)
            np.multiply(sens.rows_theta[joints], basis[:, None, :], out=out)
        else:  # a subclass with its own (dense or non-linear) joint Jacobian
            out[...] = np.einsum(
                "jxn,njk->kxn", sens.rows_theta, self.joint_jacobian(inputs, values)
            )
        return True


class Compliance(JointAngleEffect):
    name = "compliance"
    extrapolates = True  # a law of the arm over its whole range
    terms = ("c",)
    typical = {"c": (3e-6, 1e-5)}
    positive = True
    needs_masses = True
    description = "elastic joints: theta_i = q_i + c_i * tau_i(q), tau the gravity torque"

    def basis(self, inputs, joint, term):
        return inputs.tau[:, joint - 1]


class Transmission(JointAngleEffect):
    name = "transmission"
    terms = ("ts", "tc")
    typical = {"ts": (1e-4, 5e-4), "tc": (1e-4, 5e-4)}
    description = "gear eccentricity: theta_i = q_i + ts_i sin(q_i) + tc_i cos(q_i)"

    def basis(self, inputs, joint, term):
        qj = inputs.q[:, joint - 1]
        return np.sin(qj) if term == "ts" else np.cos(qj)


MAX_ORDER = 1000  # the highest order per turn a cyclic term may have


def order_reading(k: int) -> str:
    """What a cyclic joint error of order ``k`` (k cycles per turn of the joint) usually is."""
    if k == 1:
        return (
            "once per turn: an eccentricity of the gear or the encoder on the joint's output "
            "(the catalogue's transmission)"
        )
    if k == 2:
        return (
            "twice per turn: an elliptical part on the output side (a strain-wave gear's "
            "flexspline and circular spline, an oval bearing race) or an encoder tilted on its "
            "shaft"
        )
    if k == 3:
        return "three times per turn: a three-lobed bearing race or wave generator on the output"
    half = f"{k / 2:g}"
    return (
        f"{k} times per turn of the joint: a part that turns faster than the joint, seen at its "
        f"output. A strain-wave gear's error repeats twice per turn of its wave generator (order "
        f"{k} if the wave generator turns {half} times per output turn); a magnetic encoder's with "
        f"its pole pairs (p pole pairs on a shaft turning {k}/p times per output turn); a gear "
        f"stage's with its teeth (order {k}: {k} teeth on a wheel that turns once per output "
        "turn, or fewer on a faster one)"
    )


FAST_PARTS = (
    "a part that turns faster than the joint, seen at its output: a strain-wave gear's error "
    "repeats twice per turn of its wave generator (order 2r if it turns r times per output "
    "turn), a magnetic encoder's with its pole pairs (p pole pairs on a shaft turning s times "
    "per output turn: order p*s), a gear stage's with its teeth"
)


def cyclic_readings(orders: Mapping[int, Sequence[int]]) -> list[str]:
    """What the cyclic errors of ``orders`` (joint -> orders per turn) usually are, one line per
    kind: orders 1, 2 and 3 each their own, the higher ones together."""
    by_order: dict[int, list[int]] = {}
    for j, ks in sorted(orders.items()):
        for k in ks:
            by_order.setdefault(int(k), []).append(int(j))
    out = []
    for k in (1, 2, 3):
        if k in by_order:
            js = ", ".join(map(str, by_order[k]))
            out.append(f"order {k} (joint {js}): {order_reading(k)}")
    high = sorted(k for k in by_order if k > 3)
    if high:
        out.append(f"orders {', '.join(map(str, high))}: {FAST_PARTS}")
    return out


_CYCLIC_SYNTAX = (
    "cyclic[2:17,29] (orders 17 and 29 of joint 2); several joints: cyclic[2:17,29;4:2]"
)


class Cyclic(JointAngleEffect):
    """Cyclic joint errors of chosen orders per joint: ``theta_j = q_j + sum_k cs{j}_{k}
    sin(k q_j) + cc{j}_{k} cos(k q_j)``, for the orders k of joint j named in the
    specification, ``cyclic[2:17,29;4:2,40]`` (orders 17 and 29 of joint 2, 2 and 40 of joint
    4; ``a-b`` is a range of orders). An order k repeats k times per turn of the joint: order 1
    is the catalogue's ``transmission``; the higher orders come from the gears and encoders that
    turn faster than the joint (:func:`order_reading`). ``lab.spectral`` finds which orders a data
    set needs; the diagnosis does not test this effect whole (``scan_only``)."""

    name = "cyclic"
    typical = {"cs": (5e-5, 3e-4), "cc": (5e-5, 3e-4)}
    description = (
        "cyclic joint errors: theta_j = q_j + sum over the orders k of joint j of "
        "cs{j}_{k} sin(k q_j) + cc{j}_{k} cos(k q_j)"
    )
    scan_only = True
    example = "cyclic[2:17,29;4:2]"

    def __init__(
        self,
        orders: Mapping[int, Sequence[int]] | None = None,
        joints: Sequence[int] | None = None,
    ) -> None:
        if orders is None or joints is not None:
            raise EffectError(f"effect 'cyclic' needs its joints and orders: {_CYCLIC_SYNTAX}")
        clean: dict[int, tuple[int, ...]] = {}
        for j, ks in orders.items():
            if not (isinstance(j, int | np.integer) and 1 <= j <= 6):
                raise EffectError(f"effect 'cyclic': joints must be within 1..6, got {j!r}")
            ks = tuple(sorted({int(k) for k in ks}))
            if not ks:
                raise EffectError(f"effect 'cyclic': joint {j} has no orders; {_CYCLIC_SYNTAX}")
            bad = [k for k in ks if not 1 <= k <= MAX_ORDER]
            if bad:
                raise EffectError(
                    f"effect 'cyclic': orders of joint {j} must lie within 1..{MAX_ORDER}, got "
                    f"{', '.join(map(str, bad))}"
                )
            clean[int(j)] = ks
        if not clean:
            raise EffectError(f"effect 'cyclic' needs at least one joint: {_CYCLIC_SYNTAX}")
        super().__init__(joints=sorted(clean))
        self.orders: dict[int, tuple[int, ...]] = dict(sorted(clean.items()))

    @classmethod
    def from_spec(cls, brackets: str | None, spec: str = "") -> Effect:
        if brackets is None or not brackets.strip():
            raise EffectError(
                f"effect specification {spec or 'cyclic'!r}: cyclic needs its joints and "
                f"orders: {_CYCLIC_SYNTAX}"
            )
        orders: dict[int, list[int]] = {}
        for part in brackets.split(";"):
            m = re.fullmatch(r"\s*([0-9]+)\s*:\s*([0-9,\s-]+?)\s*", part)
            if not m:
                raise EffectError(
                    f"bad joint and orders {part.strip()!r} in effect specification {spec!r}; "
                    f"expected {_CYCLIC_SYNTAX}"
                )
            j = int(m.group(1))
            if j in orders:
                raise EffectError(f"joint {j} is named twice in effect specification {spec!r}")
            ks: list[int] = []
            for item in m.group(2).split(","):
                item = item.strip()
                r = re.fullmatch(r"([0-9]+)(?:\s*-\s*([0-9]+))?", item)
                if not r:
                    raise EffectError(
                        f"bad order {item!r} of joint {j} in effect specification {spec!r}; "
                        "an order is a whole number (17) or a range (2-8)"
                    )
                lo, hi = int(r.group(1)), int(r.group(2) or r.group(1))
                if hi < lo or hi - lo > MAX_ORDER:
                    raise EffectError(
                        f"bad range of orders {item!r} of joint {j} in effect specification "
                        f"{spec!r}"
                    )
                ks += range(lo, hi + 1)
            orders[j] = ks
        return cls(orders)

    @classmethod
    def from_parameters(cls, names: Sequence[str]) -> Effect:
        orders: dict[int, list[int]] = {}
        for n in names:
            p = parse_parameter_name(n)
            if p is None or p.family not in ("cs", "cc") or p.number is None or p.order is None:
                raise EffectError(f"{n!r} is not a parameter of the cyclic effect (cs2_17, cc2_17)")
            orders.setdefault(p.number, []).append(p.order)
        return cls(orders)

    @property
    def label(self) -> str:
        return (
            "cyclic[" + ";".join(f"{j}:{_orders_text(ks)}" for j, ks in self.orders.items()) + "]"
        )

    def parameter_terms(self) -> list[tuple[int, str]]:
        return [(j, f"{t}{k}") for j, ks in self.orders.items() for k in ks for t in "sc"]

    def parameter_names(self, robot: RobotDescription, targets: Sequence[int]) -> list[str]:
        return [f"c{t[0]}{j}_{t[1:]}" for j, t in self.parameter_terms()]

    def basis(self, inputs, joint, term):
        angle = int(term[1:]) * inputs.q[:, joint - 1]
        return np.sin(angle) if term[0] == "s" else np.cos(angle)


def _orders_text(ks: Sequence[int]) -> str:
    """``1-4,17,29``: runs of three or more consecutive orders as ranges."""
    out: list[str] = []
    i = 0
    while i < len(ks):
        j = i
        while j + 1 < len(ks) and ks[j + 1] == ks[j] + 1:
            j += 1
        if j - i >= 2:
            out.append(f"{ks[i]}-{ks[j]}")
        else:
            out += [str(k) for k in ks[i : j + 1]]
        i = j + 1
    return ",".join(out)


class JointScale(JointAngleEffect):
    name = "joint_scale"
    # Not a law over the whole range as fitted: a line in q_i identified over part of a joint's
    # range is its local slope, which no fit can tell from that of the joint's other errors
    # (the UR10's series B, its joint scales carried 2-6 rad beyond its range, missed series D
    # by 1.11x the geometric fit's). Outside the fitted range it is left out (lab.domain).
    terms = ("g",)
    typical = {"g": (1e-4, 5e-4)}
    description = "gear-ratio error: theta_i = q_i + g_i q_i"

    def basis(self, inputs, joint, term):
        return inputs.q[:, joint - 1]


class Backlash(JointAngleEffect):
    name = "backlash"
    extrapolates = True  # a law of the arm over its whole range
    terms = ("bl",)
    typical = {"bl": (3e-4, 6e-4)}
    positive = True
    columns = ("dir1", "dir2", "dir3", "dir4", "dir5", "dir6")
    description = "friction-held backlash: theta_i = q_i - bl_i/2 dir_i (lags the last motion)"

    def basis(self, inputs, joint, term):
        return -0.5 * inputs.column(f"dir{joint}")


class LoadBacklash(JointAngleEffect):
    """Where gravity loads a joint, its link rests against the side of the gap that the gravity
    torque pushes it to: ``theta_i = q_i + lb_i/2 sign(tau_i(q))``.

    Near zero torque gravity picks no side (friction and the last motion do): a pose whose
    torque about an active joint lies within :attr:`torque_band` (0.5 N·m) is *ambiguous*
    (:meth:`ambiguous`). The law keeps the sign there: a pose that landed on the other side
    misses by the whole gap, stands out, and the lab's outlier screening leaves it out and names
    it as ambiguous. (A smooth transition, ``tanh(tau / tau0)``, was measured to do worse: it
    halves such a pose's miss, into the range where it is neither fitted nor flagged, and
    mis-models every pose within the band of an arm whose gravity does pick the side.)"""

    name = "load_backlash"
    extrapolates = True  # a law of the arm over its whole range
    terms = ("lb",)
    typical = {"lb": (3e-4, 6e-4)}
    positive = True
    needs_masses = True
    description = "gravity-loaded backlash: theta_i = q_i + lb_i/2 sign(tau_i(q))"

    torque_band: ClassVar[float] = 0.5  # N·m: within it gravity does not pick the side
    # Below this the gravity torque is rounding noise (tau_1 and tau_6 of the seed arm are zero
    # by construction but come out as +-1e-15): its sign must not pick a side of the gap.
    zero_torque: ClassVar[float] = 1e-9  # N·m

    def basis(self, inputs, joint, term):
        tau = inputs.tau[:, joint - 1]
        return 0.5 * np.where(np.abs(tau) < self.zero_torque, 0.0, np.sign(tau))

    def ambiguous(self, inputs: ModelInputs) -> np.ndarray:
        """(N, 6): the poses whose gravity torque about an active joint lies within the band
        (and is not zero by construction): which side of the gap they rest on, gravity does
        not say."""
        out = np.zeros((inputs.n, 6), dtype=bool)
        for j in self.active_joints():
            t = np.abs(inputs.tau[:, j - 1])
            out[:, j - 1] = (t >= self.zero_torque) & (t < self.torque_band)
        return out

    def ambiguity_note(self, inputs: ModelInputs, i: int) -> str | None:
        amb = np.flatnonzero(self.ambiguous(inputs)[i])
        if not amb.size:
            return None
        taus = ", ".join(f"tau{j + 1} = {inputs.tau[i, j]:+.3g} N·m" for j in amb)
        return (
            f"ambiguous for {self.name}: {taus}, within +-{self.torque_band:g} N·m, where "
            "gravity does not pick the side of the gap"
        )


# --------------------------------------------------------------------------------------------------
class ChainEffect(Effect):
    """An effect on the chain's geometry. ``order`` sets the order of application."""

    order: ClassVar[int] = 100

    def apply(
        self, inputs: ModelInputs | None, values: np.ndarray, state: ChainState
    ) -> ChainState:
        """The chain with this effect applied; ``inputs`` is None where no poses are given (an
        effect without measured ``columns`` must not need them)."""
        raise NotImplementedError

    def jacobian(
        self, inputs: ModelInputs, values: np.ndarray, sens: Sensitivities
    ) -> np.ndarray | None:
        """(N, 3, k) derivatives of the measured point, or None to differentiate numerically."""
        return None

    def jacobian_into(
        self, inputs: ModelInputs, values: np.ndarray, sens: Sensitivities, out: np.ndarray
    ) -> bool:
        """Write the derivatives component-major, (k, 3, N), into ``out``; False when the effect
        has no analytic columns. The catalogue overrides this (and derives ``jacobian`` from it);
        a user's effect may implement either."""
        J = self.jacobian(inputs, values, sens)
        if J is None:
            return False
        out[...] = np.asarray(J).transpose(2, 1, 0)
        return True

    def _jacobian_from_into(self, inputs, values, sens) -> np.ndarray:
        out = np.empty((len(values), 3, inputs.n))
        self.jacobian_into(inputs, values, sens, out)
        return out.transpose(2, 1, 0)


_Index = np.ndarray | slice  # positions as an index array, or a slice where consecutive


@dataclass(frozen=True)
class _Slots:
    """Where the geometric parameters sit: per DH family (``alpha``, ``a``, ``theta``, ``d``,
    ``beta``) the positions in the effect's vector and the chain rows they correct; the base's six
    positions; the tool offsets' positions, one row of three per target."""

    rows: dict[str, tuple[_Index, _Index]]
    base: np.ndarray  # (6,), or (S, 6) with several stations
    tool: np.ndarray
    tool_rotation: np.ndarray | None = None  # trx, try, trz with an orientation measured


class Geometric(ChainEffect):
    """DH errors of every row, Hayati's beta on parallel consecutive axes (replacing that row's d),
    the base transform (measurement frame <- robot base) and the tool offset of each target.

    ``dalpha{i}, da{i}, dtheta{i}, dd{i}`` are the errors of row i (alpha_{i-1}, a_{i-1}, theta_i,
    d_i); ``beta{i-1}`` replaces ``dd{i}`` where z_{i-1} and z_i are parallel; ``bx by bz`` (m) and
    ``brx bry brz`` (rotation vector, rad) are the base transform itself, starting from the
    description's (``bx1``... with several tracker stations, one base each); ``tx ty tz``
    (``tx1``... with several targets) are offsets added to the tool point; ``trx try trz``, where
    an orientation is measured, the tool frame's rotation in the last frame (rotation vector,
    rad).
    """

    name = "geometric"
    order = 0
    typical = {
        "dalpha": (6e-4, 1.5e-3),
        "dtheta": (6e-4, 1.5e-3),
        "beta": (6e-4, 1.5e-3),
        "da": (1e-4, 3e-4),
        "dd": (1e-4, 3e-4),
        "b": (2e-4, 1e-3),  # base: small for the seed arm (m, rad)
        "t": (1e-4, 3e-4),  # tool offsets
        "tr": (2e-4, 1e-3),  # the tool frame's rotation: small for a probe aligned to the flange
    }
    description = "DH errors (Hayati beta on parallel axes), base transform and tool offsets"
    # 10 mm for a length error, 50 mrad (2.9 deg) for an angle error: a machined arm is never
    # that far from its drawing. The base and the tool are exempt: a tracker stands metres from
    # the base, anyhow rotated, and a reflector may sit hundreds of millimetres off the flange.
    bounds = {"da": 0.01, "dd": 0.01, "dalpha": 0.05, "dtheta": 0.05, "beta": 0.05}

    def plausible_bound(self, name: str) -> float | None:
        parsed = parse_parameter_name(name)
        if parsed is None or parsed.kind in ("base", "tool", "tool_rotation"):
            return None
        return self.bounds.get(parsed.family)

    def parameter_names(
        self,
        robot: RobotDescription,
        targets: Sequence[int],
        stations: Sequence[int] = (0,),
        orientation: bool = False,
    ) -> list[str]:
        parallel = robot.parallel_rows()
        names = [f"dalpha{i}" for i in range(1, 7)]
        names += [f"da{i}" for i in range(1, 7)]
        names += [f"dtheta{i}" for i in range(1, 7)]
        names += [f"dd{i}" for i in range(1, 7) if i not in parallel]
        names += [f"beta{i - 1}" for i in parallel]
        if len(stations) == 1:
            names += list(BASE_NAMES)
        else:
            names += [f"{c}{s}" for s in stations for c in BASE_NAMES]
        if len(targets) == 1:
            names += ["tx", "ty", "tz"]
        else:
            names += [f"{c}{k}" for k in targets for c in ("tx", "ty", "tz")]
        if orientation:
            names += list(TOOL_ROTATION_NAMES)
        return names

    def nominal(self, robot: RobotDescription, names: Sequence[str]) -> np.ndarray:
        base = dict(zip(("bx", "by", "bz"), robot.base_translation, strict=True))
        base |= dict(zip(("brx", "bry", "brz"), robot.base_rotation, strict=True))
        # a calibrated 6-DoF tool frame is kept among the description's effect values
        base |= {
            n: v for n, v in robot.effects.get(self.name, {}).items() if n in TOOL_ROTATION_NAMES
        }

        def start(n: str) -> float:
            parsed = parse_parameter_name(n)
            if parsed is not None and parsed.kind == "base":
                return base[parsed.family]
            return base.get(n, 0.0)

        return np.array([start(n) for n in names], dtype=float)

    def _slots(self, state: ChainState) -> _Slots:
        """Where each row's parameters sit in this effect's vector, once per (robot, targets,
        stations, orientation)."""
        key = (state.robot.parallel_rows(), state.targets, state.stations, state.orientation)
        cache = self.__dict__.setdefault("_slot_cache", {})
        if key not in cache:
            names = self.parameter_names(
                state.robot, state.targets, state.stations, state.orientation
            )
            cache[key] = self._compute_slots(names)
        return cache[key]

    @staticmethod
    def _compute_slots(names: Sequence[str]) -> _Slots:
        idx = {n: k for k, n in enumerate(names)}

        def rows(prefix: str, offset: int = 0) -> tuple[_Index, _Index]:
            """(positions in the vector, DH rows 0..5) of the parameters present; a slice when
            the positions are consecutive, so the columns are written without a gather."""
            pairs = [
                (idx[f"{prefix}{i + offset}"], i - 1)
                for i in range(1, 7)
                if f"{prefix}{i + offset}" in idx
            ]
            at = np.array([d for d, _ in pairs], dtype=int)
            of = np.array([r for _, r in pairs], dtype=int)
            dst: _Index = at
            src: _Index = of
            if len(at) and np.all(np.diff(at) == 1):
                dst = slice(int(at[0]), int(at[-1]) + 1)
            if len(of) and np.all(np.diff(of) == 1):
                src = slice(int(of[0]), int(of[-1]) + 1)
            return dst, src

        tool = [idx[n] for n in names if (p := parse_parameter_name(n)) and p.kind == "tool"]
        base = [idx[n] for n in names if (p := parse_parameter_name(n)) and p.kind == "base"]
        turn = [idx[n] for n in TOOL_ROTATION_NAMES if n in idx]
        return _Slots(
            rows={
                "alpha": rows("dalpha"),
                "a": rows("da"),
                "theta": rows("dtheta"),
                "d": rows("dd"),
                "beta": rows("beta", -1),
            },
            base=np.array(base, dtype=int).reshape(-1, 6) if len(base) > 6 else np.array(base),
            tool=np.array(tool, dtype=int).reshape(-1, 3),
            tool_rotation=np.array(turn, dtype=int) if turn else None,
        )

    def apply(self, inputs, values, state):
        s = self._slots(state)

        def add(base, key):
            dst, src = s.rows[key]
            out = np.array(base, dtype=float, copy=True)
            out[..., src] += values[dst]
            return out

        chain = state.chain.replace(
            alpha=add(state.chain.alpha, "alpha"),
            a=add(state.chain.a, "a"),
            theta_offset=add(state.chain.theta_offset, "theta"),
            d=add(state.chain.d, "d"),
            beta=add(state.chain.beta, "beta"),
        )
        b = values[s.base]
        tools = state.tools + values[s.tool]
        extra = {}
        if b.ndim == 2:  # one base per station; the first is also the base
            R = rotation_matrix(b[:, 3:])
            extra = {"station_t": b[:, :3], "station_r": b[:, 3:], "station_R": R}
            b = b[0]
        if s.tool_rotation is not None:
            tr = values[s.tool_rotation]
            extra |= {"tool_r": tr, "tool_R": rotation_matrix(tr)}
        return state.replace(
            chain=chain,
            base_t=b[:3],
            base_r=b[3:],
            base_R=rotation_matrix(b[3:]),
            tools=tools,
            **extra,
        )

    def jacobian(self, inputs, values, sens):
        return self._jacobian_from_into(inputs, values, sens)

    def jacobian_into(self, inputs, values, sens, out):
        s = self._slots(sens.state)
        for key, rows in (
            ("alpha", "rows_alpha"),
            ("a", "rows_a"),
            ("theta", "rows_theta"),
            ("d", "rows_d"),
        ):
            dst, src = s.rows[key]
            if isinstance(dst, slice) or len(dst):
                out[dst] = getattr(sens, rows)[src]
        dst, src = s.rows["beta"]  # only the few parallel rows have one
        if isinstance(dst, slice) or len(dst):
            out[dst] = sens.beta_rows(src)
        # lengths a and d scale with thermal growth: d p / d(da) = s * d p / d(a)
        if sens.state.length_scale is not None:
            for key in ("a", "d"):
                out[s.rows[key][0]] *= sens.state.length_scale
        if s.base.ndim == 2:
            for k, cols in enumerate(s.base):
                out[cols] = sens.base_cols * (inputs.stations == k)
        else:
            out[s.base] = sens.base_cols
        if s.tool_rotation is not None:
            out[s.tool_rotation] = sens.tool_rotation_cols
        tool = sens.tool_cols
        if len(s.tool) == 1:
            out[s.tool[0]] = tool
        else:
            for k, cols in enumerate(s.tool):
                out[cols] = tool * (inputs.target == k)
        return True


class Thermal(ChainEffect):
    """Lengths a and d (nominal plus error) scaled by ``1 + kappa (T - 20 degC)``; base and tool not."""

    name = "thermal"
    order = 10
    typical = {"kappa": (1.2e-5, 2.3e-5)}
    positive = True
    columns = ("temperature",)
    description = "thermal growth: a, d scaled by 1 + kappa (T - 20 degC)"

    def parameter_names(self, robot, targets):
        return ["kappa"]

    def _dT(self, inputs):
        return inputs.column("temperature") - REFERENCE_TEMPERATURE

    def apply(self, inputs, values, state):
        scale = 1.0 + values[0] * self._dT(inputs)
        chain = state.chain.replace(
            a=np.asarray(state.chain.a)[None, :] * scale[:, None],
            d=np.asarray(state.chain.d)[None, :] * scale[:, None],
        )
        prev = state.length_scale if state.length_scale is not None else 1.0
        return state.replace(chain=chain, length_scale=prev * scale)

    def jacobian(self, inputs, values, sens):
        return self._jacobian_from_into(inputs, values, sens)

    def jacobian_into(self, inputs, values, sens, out):
        # d p / d kappa = sum_i (d p / d a_i) a_i' + (d p / d d_i) d_i', a' = a_nominal dT
        dT = self._dT(inputs)
        a = np.asarray(sens.state.chain.a, dtype=float)
        d = np.asarray(sens.state.chain.d, dtype=float)
        a = a[:, None, None] if a.ndim == 1 else a.T[:, None, :]
        d = d[:, None, None] if d.ndim == 1 else d.T[:, None, :]
        col = (sens.rows_a * a).sum(axis=0) + (sens.rows_d * d).sum(axis=0)
        out[0] = col * (dT / (1.0 + values[0] * dT))
        return True


def missing_inputs(effect: Effect, robot: RobotDescription, columns: Sequence[str]) -> str | None:
    """What ``effect`` cannot be fitted without and the data or the arm lack, as a phrase
    ("the measured column temperature", "the arm's mass model: ..."), or None."""
    missing = [c for c in effect.columns if c not in columns]
    if missing:
        return f"the measured column(s) {', '.join(missing)}"
    if effect.needs_masses and not robot.has_mass_model:
        return (
            f"the arm's mass model: robot {robot.name!r} has no link masses, its gravity "
            "torques are zero; give each joint's mass and com in its TOML"
        )
    return None


# --------------------------------------------------------------------------------------------------
EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Add an effect class to the catalogue (usable as a decorator). A name of the catalogue's
    own effects cannot be taken by another class: it would silently change what ``compliance``
    means (a user's module that did gave a fit of 0.30 mm instead of 0.023)."""
    if not (isinstance(cls, type) and issubclass(cls, Effect)) or not cls.name:
        raise EffectError(f"{cls!r} is not an Effect subclass with a name")
    if not isinstance(cls.name, str) or not re.fullmatch(r"[a-z][a-z0-9_]*", cls.name):
        where = _SOURCES.get(cls, cls.__module__)
        raise EffectError(
            f"{where}: class {cls.__qualname__}: effect name {cls.name!r} must be lower-case "
            "letters, digits, _"
        )
    old = EFFECTS.get(cls.name)
    if old is not None and old is not cls:
        if is_catalogued(old) or old.__qualname__ in _ENTRY_POINT_CLASSES:
            raise EffectError(
                f"{effect_origin(cls)}: class {cls.__qualname__} takes the name {cls.name!r} of "
                f"the catalogue's {old.__module__}.{old.__qualname__}; give it another name"
            )
        log.info("effect %r replaced by %s", cls.name, cls.__qualname__)
    EFFECTS[cls.name] = cls
    return cls


_ENTRY_POINT_CLASSES: set[str] = set()


for _cls in (
    Geometric,
    Compliance,
    Transmission,
    Cyclic,
    JointScale,
    Backlash,
    LoadBacklash,
    Thermal,
):
    register_effect(_cls)
CATALOGUE: tuple[str, ...] = tuple(EFFECTS)

_entry_points_loaded = False


def _load_entry_points() -> None:
    global _entry_points_loaded
    if _entry_points_loaded:
        return
    _entry_points_loaded = True
    for ep in importlib.metadata.entry_points(group="sixaxis.effects"):
        try:
            cls = register_effect(ep.load())
            _ENTRY_POINT_CLASSES.add(cls.__qualname__)
        except Exception as exc:  # a broken plug-in must not break the catalogue
            log.warning("effect entry point %s could not be loaded: %s", ep.name, exc)


def load_effect_module(path: str | Path) -> list[str]:
    """Import a Python file and register every named :class:`Effect` subclass defined in it.

    Everything that can go wrong is an :class:`EffectError` of one line naming the file: not a
    regular file (a FIFO would hang the import), an exception or ``sys.exit`` while it is
    imported, no effect class, an effect that takes the name of a catalogued effect or names a
    parameter like a catalogued one (``c2``), or whose ``parameter_names`` fails."""
    path = check_input_file(path, "effect module", "python", EffectError)
    spec = importlib.util.spec_from_file_location(f"sixaxis_user_effects_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise EffectError(f"{path}: not a Python file that can be imported")
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
    except SystemExit as exc:  # the module's own sys.exit() must not end the command
        raise EffectError(
            f"{path}: the effect module called sys.exit({exc.code!r}) while being imported"
        ) from None
    except Exception as exc:
        raise EffectError(
            f"{path}: the effect module failed to import: {type(exc).__name__}: {exc}"
        ) from None
    found = [
        obj
        for obj in vars(mod).values()
        if isinstance(obj, type)
        and issubclass(obj, Effect)
        and obj.name
        and obj.__module__ == mod.__name__
    ]
    if not found:
        raise EffectError(f"{path}: defines no Effect subclass with a name")
    for cls in found:
        _SOURCES[cls] = str(path)
        _check_user_effect(cls)
    for cls in found:
        register_effect(cls)
    return [c.name for c in found]


def _check_user_effect(cls: type[Effect]) -> None:
    """Refuse a user's effect whose parameter names cannot be listed, or collide with the
    catalogue's (``c2`` is compliance's): a fit with both would have one name for two
    parameters, and every table and JSON key would be ambiguous."""
    if not isinstance(cls.name, str) or not re.fullmatch(r"[a-z][a-z0-9_]*", cls.name):
        register_effect(cls)  # refuses the name, naming the file
    if cls.name in CATALOGUE:
        own = EFFECTS[cls.name]
        raise EffectError(
            f"{effect_origin(cls)}: class {cls.__qualname__} takes the name {cls.name!r} of the "
            f"catalogue's {own.__module__}.{own.__qualname__}; give it another name"
        )
    with user_code(cls, "parameter_names(seed arm)"):
        names = list(cls().parameter_names(seed_robot(), (0,)))
    for n in names:
        if not isinstance(n, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", n):
            raise EffectError(
                f"{effect_origin(cls)}: parameter name {n!r} must be letters, digits and _"
            )
        parsed = parse_parameter_name(n)
        if parsed is not None:
            owner = next(
                (
                    e
                    for e in CATALOGUE
                    if n in EFFECTS[e]().parameter_names(seed_robot(), (0,))
                    or (parsed.kind == "tool" and e == "geometric")
                ),
                "geometric",
            )
            raise EffectError(
                f"{effect_origin(cls)}: parameter {n!r} has the name of the catalogue's "
                f"{owner} parameter {n!r}; name its terms otherwise"
            )
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise EffectError(f"{effect_origin(cls)}: parameter(s) {', '.join(dup)} named twice")


def user_module_failure(exc: BaseException) -> str | None:
    """Where a user's effect module raised ``exc``, as one line (``m.py, line 12, in basis:
    KeyError: 'x'``), or None when no frame of its traceback lies in a loaded effect module.
    A front end's last net: an exception from a user's code is theirs to fix, not a bug of
    sixaxis-track, and gets a line instead of a traceback."""
    sources = set(_SOURCES.values())
    if not sources:
        return None
    tb, last = exc.__traceback__, None
    while tb is not None:
        if tb.tb_frame.f_code.co_filename in sources:
            last = tb
        tb = tb.tb_next
    if last is None:
        return None
    code = last.tb_frame.f_code
    return (
        f"{code.co_filename}, line {last.tb_lineno}, in {code.co_name}: "
        f"{type(exc).__name__}: {exc} (an effect module's own error)"
    )


def check_robot_effects(robot: RobotDescription, source: str | None = None) -> None:
    """Refuse a description whose ``[effects.NAME]`` names no registered effect, or a parameter
    that effect does not have (``[effects.compliance] c9``): a typo must not drop a calibrated
    value silently. ``source`` (the file) is named in the message, else the robot's name."""
    where = source or f"robot {robot.name!r}"
    for name, values in robot.effects.items():
        if name not in EFFECTS:
            _load_entry_points()
        if name not in EFFECTS:
            raise EffectError(
                f"{where}: [effects.{name}]: unknown effect {name!r}; known: "
                f"{', '.join(sorted(EFFECTS))} (a user's effect needs its --effect-module)"
            )
        cls = EFFECTS[name]
        with user_code(cls, "from_parameters"):
            try:
                effect = cls.from_parameters(list(values))
            except EffectError as exc:
                raise EffectError(f"{where}: [effects.{name}]: {exc}") from None
            known = list(effect.parameter_names(robot, (0,)))
        if isinstance(effect, Geometric):  # any target's tool, any station's base, the tool frame
            geometric = {"row", "beta", "base", "tool", "tool_rotation"}
            unknown = [
                k
                for k in values
                if k not in known
                and ((p := parse_parameter_name(k)) is None or p.kind not in geometric)
            ]
        else:
            unknown = [k for k in values if k not in known]
        if unknown:
            raise EffectError(
                f"{where}: [effects.{name}]: {', '.join(map(repr, unknown))} is not a parameter "
                f"of {name} (it has {', '.join(known)})"
            )


_EFFECT_PATTERN = re.compile(r"^\s*([a-z][a-z0-9_]*)\s*(?:\[([^\]]*)\])?\s*$")


def make_effect(spec: str | Effect) -> Effect:
    """An effect from its name, ``compliance`` or restricted to joints, ``compliance[2,3]``
    (the cyclic effect names joints and orders, ``cyclic[2:17,29]``)."""
    if isinstance(spec, Effect):
        return spec
    m = _EFFECT_PATTERN.match(spec)
    if not m:
        raise EffectError(
            f"bad effect specification {spec!r}; expected e.g. 'compliance', "
            "'compliance[2,3]' or 'cyclic[2:17,29]'"
        )
    name, brackets = m.group(1), m.group(2)
    if name not in EFFECTS:
        _load_entry_points()
    if name not in EFFECTS:
        raise EffectError(f"unknown effect {name!r}; known: {', '.join(sorted(EFFECTS))}")
    return EFFECTS[name].from_spec(brackets, spec)


def candidate_effects() -> list[str]:
    """The registered effects the diagnosis tests whole (all but the scanned ones)."""
    return [n for n, cls in EFFECTS.items() if not cls.scan_only]


def parse_effects(spec: str | Sequence[str | Effect]) -> list[Effect]:
    """``"geometric,compliance[2,3]"`` or a list of names/effects -> effect instances."""
    if isinstance(spec, str):
        parts = re.findall(r"[^,\[]+(?:\[[^\]]*\])?", spec)
        spec = [p.strip() for p in parts if p.strip()]
    effects = [make_effect(s) for s in spec]
    names = [e.name for e in effects]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise EffectError(f"effect(s) listed twice: {', '.join(sorted(dup))}")
    return effects
