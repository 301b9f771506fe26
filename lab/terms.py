"""Joint-angle terms as data: small expression trees of a joint's variables, and the effect class
built from them.

Discovery's library (:mod:`lab.discovery`) holds each candidate function ``f`` of the measured
variables as a tree of :class:`Expr` nodes. A tree is evaluated on arrays (:meth:`Expr.value`)
and written as the Python text of an effect module's ``basis`` (:meth:`Expr.code`): the module
``sixaxis lab discover -o`` writes runs that text, and the lab runs the same tree
(:func:`term_effect`) with the same numpy operations in the same order, so the two agree to the
bit. Nothing is parsed, ``eval``'d or ``exec``'d.

The variables of a term on joint j (the local names of the written ``basis``): ``q`` (q_j),
``tau`` (the gravity torque of joint j), ``dT`` (temperature - 20 degC), ``t``, ``payload``,
``direction`` (dir_j).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from arm.effect_api import ModelInputs
from arm.effects import REFERENCE_TEMPERATURE, JointAngleEffect
from arm.errors import EffectError

__all__ = ["Expr", "Fn", "Mul", "Pow", "Scaled", "TermEffect", "Var", "term_effect"]


class Expr:
    """A node of a term's expression tree."""

    def code(self) -> str:
        """The Python text of the node, as the written module's ``basis`` runs it."""
        raise NotImplementedError

    def value(self, env: Mapping[str, np.ndarray | None]) -> np.ndarray:
        """The node's value, with ``env`` giving each variable's array."""
        raise NotImplementedError

    def variables(self) -> set[str]:
        raise NotImplementedError


@dataclass(frozen=True)
class Var(Expr):
    """A variable of the joint: ``q``, ``tau``, ``dT``, ``t``, ``payload`` or ``direction``."""

    name: str

    def code(self) -> str:
        return self.name

    def value(self, env: Mapping[str, np.ndarray | None]) -> np.ndarray:
        v = env[self.name]
        if v is None:
            raise EffectError(f"the data have no {self.name!r} for this term")
        return v

    def variables(self) -> set[str]:
        return {self.name}


@dataclass(frozen=True)
class Scaled(Expr):
    """``m * x``: a harmonic's angle."""

    m: int
    x: Expr

    def code(self) -> str:
        return f"{self.m} * {self.x.code()}"

    def value(self, env: Mapping[str, np.ndarray | None]) -> np.ndarray:
        return self.m * self.x.value(env)

    def variables(self) -> set[str]:
        return self.x.variables()


@dataclass(frozen=True)
class Fn(Expr):
    """A numpy function of one argument: ``np.sin(x)``, ``np.cos(x)``, ``np.sign(x)``."""

    name: str
    x: Expr

    def code(self) -> str:
        return f"np.{self.name}({self.x.code()})"

    def value(self, env: Mapping[str, np.ndarray | None]) -> np.ndarray:
        return getattr(np, self.name)(self.x.value(env))

    def variables(self) -> set[str]:
        return self.x.variables()


@dataclass(frozen=True)
class Pow(Expr):
    """``x**n``."""

    x: Expr
    n: int

    def code(self) -> str:
        return f"{self.x.code()}**{self.n}"

    def value(self, env: Mapping[str, np.ndarray | None]) -> np.ndarray:
        return self.x.value(env) ** self.n

    def variables(self) -> set[str]:
        return self.x.variables()


@dataclass(frozen=True)
class Mul(Expr):
    """``a * b``."""

    a: Expr
    b: Expr

    def code(self) -> str:
        return f"{self.a.code()} * {self.b.code()}"

    def value(self, env: Mapping[str, np.ndarray | None]) -> np.ndarray:
        return self.a.value(env) * self.b.value(env)

    def variables(self) -> set[str]:
        return self.a.variables() | self.b.variables()


def term_variables(
    q: np.ndarray, tau: np.ndarray, columns: Mapping[str, np.ndarray], joint: int
) -> dict[str, np.ndarray | None]:
    """The variables of a term on ``joint`` (1-based) from the joint readings ``q`` (N, 6), the
    gravity torques ``tau`` (N, 6) and the data's other columns (None where a column is
    missing)."""
    return {
        "q": q[:, joint - 1],
        "tau": tau[:, joint - 1],
        "dT": columns["temperature"] - REFERENCE_TEMPERATURE if "temperature" in columns else None,
        "t": columns.get("t"),
        "payload": columns.get("payload"),
        "direction": columns.get(f"dir{joint}"),
    }


def _inputs_variables(inputs: ModelInputs, joint: int, names: set[str]) -> dict:
    """The variables ``names`` of a term on ``joint``, read as the written module reads them."""
    env: dict[str, np.ndarray | None] = {}
    if "q" in names:
        env["q"] = inputs.q[:, joint - 1]
    if "tau" in names:
        env["tau"] = inputs.tau[:, joint - 1]
    if "dT" in names:
        env["dT"] = inputs.column("temperature") - REFERENCE_TEMPERATURE
    if "t" in names:
        env["t"] = inputs.column("t")
    if "payload" in names:
        env["payload"] = inputs.column("payload")
    if "direction" in names:
        env["direction"] = inputs.column(f"dir{joint}")
    return env


class TermEffect(JointAngleEffect):
    """``theta_j = q_j + sum over the joint's terms of k_term_j * term(variables)``: the effect
    of an expression tree per term (:func:`term_effect` makes one class per set of terms)."""

    forms: dict[int, tuple[str, ...]] = {}
    expressions: dict[str, Expr] = {}
    module_text: str = ""

    def parameter_names(self, robot, targets):
        return [f"{t}{j}" for j in self.active_joints() for t in self.forms.get(j, ())]

    def regressor(self, inputs):
        """(N, 6, k) d theta / d parameters, in the order of parameter_names."""
        cols = [
            (j, self.basis(inputs, j, t))
            for j in self.active_joints()
            for t in self.forms.get(j, ())
        ]
        out = np.zeros((inputs.n, 6, len(cols)))
        for k, (j, b) in enumerate(cols):
            out[:, j - 1, k] = b
        return out

    def basis(self, inputs, joint, term):
        expr = self.expressions.get(term)
        if expr is None:
            raise EffectError(f"unknown term {term!r}")
        used = set().union(*(e.variables() for e in self.expressions.values()))
        return expr.value(_inputs_variables(inputs, joint, used))


def term_effect(
    name: str,
    class_name: str,
    module: str,
    description: str,
    columns: tuple[str, ...],
    forms: Mapping[int, tuple[str, ...]],
    typical: Mapping[str, tuple[float, float]],
    expressions: Mapping[str, Expr],
    module_text: str = "",
) -> type[TermEffect]:
    """The effect class of these terms: ``forms`` the terms of each joint, ``expressions`` each
    term's tree (in the order of the class's ``terms``), ``typical`` each term's typical range;
    ``module`` the name its ``__module__`` gives (where an error says it comes from);
    ``module_text`` the Python text of the module that defines the same class (what an export
    writes beside a calibrated arm that uses it, so that another process can load it)."""
    attrs = {
        "__module__": module,
        "__qualname__": class_name,
        "__doc__": TermEffect.__doc__,
        "name": name,
        "description": description,
        "columns": tuple(columns),
        "forms": dict(forms),
        "terms": tuple(expressions),
        "typical": dict(typical),
        "expressions": dict(expressions),
        "module_text": module_text,
    }
    return type(class_name, (TermEffect,), attrs)
