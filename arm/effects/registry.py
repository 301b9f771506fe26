"""The registry of effects (:data:`EFFECTS`): the catalogue's, those of other packages
(the ``sixaxis.effects`` entry-point group) and a user's (``--effect-module FILE.py``, every
:class:`~arm.effects.base.Effect` subclass with a name in the file), with the checks a user's
effect passes before it is registered, and the check of a description's ``[effects.NAME]``
tables against it.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import logging
import re
from pathlib import Path

from arm.description import RobotDescription, seed_robot
from arm.effect_api import EffectError
from arm.effects.base import SOURCE_FILES, Effect, effect_origin, is_catalogued, user_code
from arm.effects.chain import Geometric, Thermal
from arm.effects.extra import ExtraJoints
from arm.effects.joint_angle import (
    Backlash,
    Compliance,
    Cyclic,
    JointScale,
    LoadBacklash,
    Transmission,
)
from arm.effects.lumped import LumpedCompliance
from arm.files import check_input_file
from arm.params import parse_parameter_name

__all__ = [
    "CATALOGUE",
    "EFFECTS",
    "check_robot_effects",
    "load_effect_module",
    "load_entry_points",
    "register_effect",
    "user_module_failure",
]

log = logging.getLogger(__name__)

EFFECTS: dict[str, type[Effect]] = {}


def _full_name(cls: type[Effect]) -> str:
    """``arm.effects.Compliance``: where a user imports a class from (the catalogue's effects from
    the package, whichever of its modules defines them)."""
    module = __name__.rpartition(".")[0] if is_catalogued(cls) else cls.__module__
    return f"{module}.{cls.__qualname__}"


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Add an effect class to the catalogue (usable as a decorator). A name of the catalogue's
    own effects cannot be taken by another class: it would silently change what ``compliance``
    means (a user's module that did gave a fit of 0.30 mm instead of 0.023)."""
    if not (isinstance(cls, type) and issubclass(cls, Effect)) or not cls.name:
        raise EffectError(f"{cls!r} is not an Effect subclass with a name")
    if not isinstance(cls.name, str) or not re.fullmatch(r"[a-z][a-z0-9_]*", cls.name):
        where = SOURCE_FILES.get(cls, cls.__module__)
        raise EffectError(
            f"{where}: class {cls.__qualname__}: effect name {cls.name!r} must be lower-case "
            "letters, digits, _"
        )
    old = EFFECTS.get(cls.name)
    if old is not None and old is not cls:
        if is_catalogued(old) or old.__qualname__ in _ENTRY_POINT_CLASSES:
            raise EffectError(
                f"{effect_origin(cls)}: class {cls.__qualname__} takes the name {cls.name!r} of "
                f"the catalogue's {_full_name(old)}; give it another name"
            )
        log.info("effect %r replaced by %s", cls.name, cls.__qualname__)
    EFFECTS[cls.name] = cls
    return cls


_ENTRY_POINT_CLASSES: set[str] = set()


for _cls in (
    Geometric,
    Compliance,
    LumpedCompliance,
    Transmission,
    Cyclic,
    JointScale,
    Backlash,
    LoadBacklash,
    Thermal,
    ExtraJoints,
):
    register_effect(_cls)
CATALOGUE: tuple[str, ...] = tuple(EFFECTS)

_entry_points_loaded = False


def load_entry_points() -> None:
    """Register the effects of other packages (the ``sixaxis.effects`` entry-point group), once;
    one that fails to load is logged and left out."""
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
        SOURCE_FILES[cls] = str(path)
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
            f"catalogue's {_full_name(own)}; give it another name"
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
    sources = set(SOURCE_FILES.values())
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
            load_entry_points()
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
