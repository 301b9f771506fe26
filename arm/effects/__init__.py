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
:class:`Effect` subclass with a name in the file is registered) or from another package through
the ``sixaxis.effects`` entry-point group.

One module a job; import from the package, ``from arm.effects import JointAngleEffect``:

* :mod:`arm.effects.base`: the base classes, and how a user's effect code is run and named;
* :mod:`arm.effects.joint_angle`: the catalogue's joint-angle effects (compliance, cyclic...);
* :mod:`arm.effects.chain`: the catalogue's chain effects (geometric, thermal);
* :mod:`arm.effects.lumped`: compliance without a mass model (lumped_compliance);
* :mod:`arm.effects.extra`: the robot's extra joints (a column's scale and tilt: extra_joints);
* :mod:`arm.effects.registry`: the registry, entry points, ``--effect-module`` and the checks a
  user's effect passes;
* :mod:`arm.effects.specs`: effects from their specifications (``compliance[2,3]``).
"""

from __future__ import annotations

from arm.effects.base import (
    PLAUSIBLE_FACTOR,
    ChainEffect,
    Effect,
    JointAngleEffect,
    effect_module_file,
    effect_origin,
    is_catalogued,
    missing_inputs,
    plausible_bound_of,
    user_code,
)
from arm.effects.chain import REFERENCE_TEMPERATURE as REFERENCE_TEMPERATURE
from arm.effects.chain import Geometric, Thermal
from arm.effects.extra import ExtraJoints as ExtraJoints
from arm.effects.joint_angle import (
    FAST_PARTS,
    Backlash,
    Compliance,
    Cyclic,
    JointScale,
    LoadBacklash,
    Transmission,
    cyclic_readings,
    order_reading,
)
from arm.effects.joint_angle import MAX_ORDER as MAX_ORDER
from arm.effects.lumped import LumpedCompliance, lumped_values
from arm.effects.registry import CATALOGUE as CATALOGUE
from arm.effects.registry import (
    EFFECTS,
    check_robot_effects,
    load_effect_module,
    register_effect,
    user_module_failure,
)
from arm.effects.specs import candidate_effects, make_effect, parse_effects, union_of

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
    "LumpedCompliance",
    "Thermal",
    "Transmission",
    "candidate_effects",
    "check_robot_effects",
    "cyclic_readings",
    "effect_module_file",
    "effect_origin",
    "is_catalogued",
    "load_effect_module",
    "lumped_values",
    "make_effect",
    "missing_inputs",
    "order_reading",
    "parse_effects",
    "plausible_bound_of",
    "register_effect",
    "union_of",
    "user_code",
    "user_module_failure",
]
