"""The effects' base classes (:class:`Effect`, :class:`JointAngleEffect`,
:class:`ChainEffect`), what every effect is checked against (:data:`PLAUSIBLE_FACTOR`,
:data:`MAX_BASIS`), and how a user's effect code is run (:func:`user_code`) and named in an error
(:func:`effect_origin`).
"""

from __future__ import annotations

import contextlib
import inspect
from collections.abc import Iterator, Sequence
from typing import ClassVar

import numpy as np

from arm.description import RobotDescription
from arm.effect_api import ArmSize, ChainState, EffectError, ModelInputs, Sensitivities
from arm.errors import SixAxisError

__all__ = [
    "MAX_BASIS",
    "PLAUSIBLE_FACTOR",
    "SOURCE_FILES",
    "ChainEffect",
    "Effect",
    "JointAngleEffect",
    "effect_origin",
    "is_catalogued",
    "missing_inputs",
    "plausible_bound_of",
    "user_code",
]

# An identified parameter is implausible beyond this many times the top of its typical range:
# a compliance ten times that of a soft harmonic drive, a gap of 20 arcmin, kappa of 2.3e-4/K
# (ten times aluminium's) come from the data's units or another robot, not from the arm.
PLAUSIBLE_FACTOR = 10.0
#: the largest value a basis (a joint-angle regressor) may take: far from overflow when squared,
#: as the readers' bound on any other column (arm.ranges.MAX_EXTRA)
MAX_BASIS = 1e12
#: the file each --effect-module class was loaded from (arm.effects.registry fills it)
SOURCE_FILES: dict[type, str] = {}
# the package whose modules hold the catalogue's own effects and their base classes
_PACKAGE = __name__.rpartition(".")[0] + "."


def effect_module_file(effect: Effect | type[Effect]) -> str | None:
    """The file an ``--effect-module`` effect was loaded from (None: the catalogue's, an entry
    point's, or a class made in memory)."""
    cls = effect if isinstance(effect, type) else type(effect)
    return SOURCE_FILES.get(cls)


def effect_origin(effect: Effect | type[Effect]) -> str:
    """``effect 'mine' (module /path/mine.py)``: the effect and the file that defines it, as an
    error names them."""
    cls = effect if isinstance(effect, type) else type(effect)
    where = SOURCE_FILES.get(cls)
    if where is None:
        try:
            where = inspect.getsourcefile(cls) or cls.__module__
        except TypeError:
            where = cls.__module__
    return f"effect {cls.name!r} (module {where})"


def is_catalogued(effect: Effect | type[Effect]) -> bool:
    """Whether ``effect`` is one of the catalogue's own (defined in this package)."""
    cls = effect if isinstance(effect, type) else type(effect)
    return cls.__module__.startswith(_PACKAGE)


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
    # ... or the robot's extra joints (a column, a track: arm.extra_joints), whose corrections
    # it fits; on an arm without any it has no parameters.
    needs_extra_joints: ClassVar[bool] = False
    # The largest plausible magnitude of each parameter family (name prefix), SI units; None
    # exempts a family. A family without one is bounded by PLAUSIBLE_FACTOR times the top of its
    # typical range; an identified value beyond its bound is an error (units, another robot,
    # another convention) unless the user accepts it (lab.plausibility).
    bounds: ClassVar[dict[str, float | None]] = {}
    # The families (name prefixes) that are lengths of the arm: their bound grows with the
    # arm's size (ArmSize.length_factor: 1 up to a UR10's, in proportion beyond), as a DH
    # length's does; the others keep theirs at any size.
    lengths: ClassVar[tuple[str, ...]] = ()
    # The catalogue effect this one stands in for where that one cannot be fitted (the mass-free
    # lumped_compliance for compliance): the diagnosis tests it only where the other is not.
    stands_in_for: ClassVar[str] = ""
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

    def plausible_bound(self, name: str, arm: ArmSize | None = None) -> float | None:
        """The largest plausible magnitude of parameter ``name`` (SI) on an arm of size ``arm``:
        from :attr:`bounds` by the longest prefix, else :data:`PLAUSIBLE_FACTOR` times the top
        of its typical range; None where the effect states neither, or exempts the family. A
        family among :attr:`lengths` has its bound times ``arm.length_factor`` (none given: the
        stated bound, that of an arm up to a UR10's size)."""
        bound = self.stated_bound(name)
        if bound is None or arm is None or not self.is_length(name):
            return bound
        return bound * arm.length_factor

    def stated_bound(self, name: str) -> float | None:
        """The bound of ``name`` as the effect states it, for an arm up to a UR10's size."""
        for prefix in sorted(self.bounds, key=len, reverse=True):
            if name.startswith(prefix):
                return self.bounds[prefix]
        rg = self.typical_range(name)
        return None if rg is None else PLAUSIBLE_FACTOR * rg[1]

    def is_length(self, name: str) -> bool:
        """Whether ``name`` belongs to one of :attr:`lengths` (by the longest prefix of
        :attr:`bounds` and :attr:`typical` it starts with, so that ``dd`` is not ``d``'s)."""
        known = [p for p in (*self.bounds, *self.typical, *self.lengths) if name.startswith(p)]
        return bool(known) and max(known, key=len) in self.lengths

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

    def parameter_joints(self, robot: RobotDescription) -> list[int]:
        """The joint of each parameter, in the order of :meth:`parameter_names`."""
        return [j for j, _ in self.parameter_terms()]

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
            np.multiply(sens.rows_joint[joints], basis[:, None, :], out=out)
        else:  # a subclass with its own (dense or non-linear) joint Jacobian
            out[...] = np.einsum(
                "jxn,njk->kxn", sens.rows_joint, self.joint_jacobian(inputs, values)
            )
        return True


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


def plausible_bound_of(effect: Effect, name: str, arm: ArmSize | None) -> float | None:
    """``effect.plausible_bound(name, arm)``: the bound of ``name`` on an arm of size ``arm``.
    A user's effect whose own ``plausible_bound(self, name)`` predates the arm's size is asked
    as it was written (its bound does not scale); what it raises is one line naming it."""
    method = type(effect).plausible_bound
    with user_code(effect, f"plausible_bound({name!r})"):
        if method is Effect.plausible_bound or _takes_arm(method):
            bound = effect.plausible_bound(name, arm)
        else:
            bound = effect.plausible_bound(name)
    if bound is None:
        return None
    try:
        value = float(bound)
    except (TypeError, ValueError):
        raise EffectError(
            f"{effect_origin(effect)}: plausible_bound({name!r}) returned {bound!r:.40}, not a "
            "number or None"
        ) from None
    if not value > 0:
        raise EffectError(
            f"{effect_origin(effect)}: plausible_bound({name!r}) returned {value:g}, not a "
            "positive number (None exempts a parameter)"
        )
    return value


def _takes_arm(method) -> bool:
    """Whether an effect's ``plausible_bound`` takes the arm's size after the name."""
    try:
        params = list(inspect.signature(method).parameters.values())
    except (TypeError, ValueError):
        return False
    if any(p.kind is inspect.Parameter.VAR_POSITIONAL for p in params):
        return True
    positional = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    return sum(p.kind in positional for p in params) >= 3  # self, name, arm


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
    if effect.needs_extra_joints and not robot.extra_joints:
        return (
            f"extra joints before the arm's base: robot {robot.name!r} has none ([[extra_joints]] "
            "in its TOML, a prismatic or revolute joint before the arm in its URDF)"
        )
    return None
