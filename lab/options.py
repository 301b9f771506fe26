"""The lab's options: one frozen object, one vocabulary, validated once.

Every lab entry point (:func:`lab.screen`, :func:`lab.fit`, :func:`lab.diagnose`,
:func:`lab.discover`, :func:`lab.report.build_report`) takes the data, the robot and the effects,
then ``options=`` one object or the fields of :class:`LabOptions` as keywords
(``**keywords: Unpack[OptionFields]``, typed once here), and resolves them once
(:func:`resolve`) into one :class:`LabOptions` that it passes down. Its checks are declared
beside each field (:mod:`arm.constraints`): a bad value is refused with the same message wherever
it is given, and every bad value at once.

    opts = LabOptions(noise_mm=0.015, loss="huber")
    lab.fit(data, "seed", "geometric", options=opts)       # the same as the keywords
    lab.fit(data, "seed", "geometric", noise_mm=-1)
    # FitError: noise_mm must be positive, got -1

The command line builds its choices and ranges from the same declarations
(:func:`arm.constraints.choices`), and the agents build the same object.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal, TypedDict

from arm.constraints import Interval, choices, declare, problems, refuse
from arm.effects import MAX_ORDER
from arm.measurements import COMPONENTS
from arm.noise import InstrumentNoise
from lab.errors import FitError, UnknownOptionError

__all__ = [
    "ALPHA",
    "CRITERIA",
    "EXPORT_FORMATS",
    "LOSSES",
    "ORDER",
    "OUTLIER_MODES",
    "ROUNDS",
    "SOLVERS",
    "LabOptions",
    "Loss",
    "OptionFields",
    "OutlierMode",
    "Solver",
]

Loss = Literal["linear", "huber", "soft_l1"]
OutlierMode = Literal["auto", "keep"]
Solver = Literal["lm", "minpack"]

POSITIVE = Interval(float, 0.0, None, closed="neither")
NON_NEGATIVE = Interval(float, 0.0, None, closed="left")


@dataclass(frozen=True)
class LabOptions:
    """How the lab fits and screens; the same for every entry point.

    ``noise_mm``: the instrument's per-axis standard uncertainty (mm), if known (else estimated
    from the residual); the identifiability pass and the diagnosis's noise test use it.
    ``loss``: ``linear`` (least squares), ``huber`` or ``soft_l1`` (robust to outliers).
    ``outliers``: ``auto`` leaves gross outliers out by the rule of :mod:`lab.screening`,
    ``keep`` fits every pose (duplicates are counted once either way). ``accept_large``: keep a
    model whose identified parameters exceed the plausible bound of their kind
    (:mod:`lab.plausibility`) instead of refusing it. ``solver``: ``lm`` (the lab's
    Levenberg-Marquardt, :mod:`lab.solver`) or ``minpack`` (scipy's ``lmder``), for the linear
    loss. ``f_scale_mm``: the robust loss's threshold (default 1.345 robust sigmas).
    ``max_evaluations``: of the model, per solve. ``register``: place a geometric model's base
    and tool offsets in closed form first (:mod:`lab.registration`).

    The instrument model (:class:`arm.noise.InstrumentNoise`, docs/format.md): ``noise_ppm``,
    the growth of the per-axis sigma with the distance from the tracker (um per m: sigma =
    ``noise_mm`` + ``noise_ppm`` x distance); ``noise_mrad``, an orientation's per-axis sigma.
    With them, or with the rows' own ``std_*`` columns, every row is weighted by its sigma and
    every test compares the residual with it. ``measured``: the components (of ``x y z rx ry
    rz``) to fit, default every one the data measured (``x,y,z``: the positions alone).
    """

    noise_mm: float | None = declare(None, POSITIVE)
    loss: Loss = "linear"
    outliers: OutlierMode = "auto"
    accept_large: bool = False
    solver: Solver = "lm"
    f_scale_mm: float | None = declare(None, POSITIVE)
    max_evaluations: int = declare(100, Interval(int, 1, None))
    register: bool = True
    noise_ppm: float = declare(0.0, NON_NEGATIVE)
    noise_mrad: float | None = declare(None, POSITIVE)
    measured: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        refuse(problems(self), FitError)
        if self.measured is not None:
            bad = [c for c in self.measured if c not in COMPONENTS]
            if bad or not {"x", "y", "z"} <= set(self.measured):
                raise FitError(
                    f"measured must name x, y, z and any of rx, ry, rz, got {','.join(self.measured)}"
                )

    @property
    def noise(self) -> float | None:
        """``noise_mm`` in m."""
        return None if self.noise_mm is None else 1e-3 * self.noise_mm

    @property
    def instrument(self) -> InstrumentNoise:
        """The instrument model these options state."""
        return InstrumentNoise(self.noise_mm, self.noise_ppm, self.noise_mrad)

    def replace(self, **changes: Any) -> LabOptions:
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class OptionFields(TypedDict, total=False):
    """The fields of :class:`LabOptions` as keywords: an entry point's ``**keywords:
    Unpack[OptionFields]`` (the one signature that spells them out; a test keeps the two alike)."""

    noise_mm: float | None
    loss: Loss
    outliers: OutlierMode
    accept_large: bool
    solver: Solver
    f_scale_mm: float | None
    max_evaluations: int
    register: bool
    noise_ppm: float
    noise_mrad: float | None
    measured: tuple[str, ...] | None


# the entry points' own settings, declared here so that the command line takes them alike
ALPHA = Interval(float, 0.0, 1.0, closed="neither")  # a family-wise rate (diagnose, discover)
ORDER = Interval(int, 1, MAX_ORDER)  # the highest order per turn discover scans
ROUNDS = Interval(int, 0, None)  # the report's rounds of diagnose-and-refit
CRITERIA = ("o1", "o4")  # lab.plan's pose-set criteria (Borm & Menq, Nahvi & Hollerbach)

LOSSES: tuple[str, ...] = choices(LabOptions, "loss")
OUTLIER_MODES: tuple[str, ...] = choices(LabOptions, "outliers")
SOLVERS: tuple[str, ...] = choices(LabOptions, "solver")
DEFAULTS = LabOptions()


def resolve(options: LabOptions | None, **given: Any) -> LabOptions:
    """The options of an entry point's call, resolved once: ``options`` if given (then every
    keyword must be left at its default: one call states each option once), else the keywords
    (:class:`OptionFields`), validated."""
    if options is None:
        return LabOptions(**given)
    if not isinstance(options, LabOptions):
        raise FitError(f"options must be a LabOptions, got {type(options).__name__}")
    unknown = [k for k in given if k not in OptionFields.__annotations__]
    if unknown:
        raise UnknownOptionError(f"unexpected keyword argument(s): {', '.join(unknown)}")
    twice = [k for k, v in given.items() if not _same(v, getattr(DEFAULTS, k))]
    if twice:
        raise FitError(
            f"{', '.join(twice)} given both as a keyword and in options=; give each option once"
        )
    return options


def _same(a: Any, b: Any) -> bool:
    return type(a) is type(b) and a == b


def check_alpha(alpha: float) -> None:
    """Refuse a family-wise rate outside (0, 1), in the declared words."""
    if not ALPHA.holds(alpha):
        raise FitError(f"alpha must {ALPHA.predicate}, got {alpha!r}")


#: what `sixaxis lab export --format` writes: a robot TOML, or the arm's URDF with its metrology
#: file beside it (lab.urdf_export)
EXPORT_FORMATS = ("toml", "urdf")
