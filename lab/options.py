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

from arm.constraints import (
    NON_NEGATIVE,
    POSITIVE,
    Interval,
    Quantity,
    choices,
    declare,
    problems,
    refuse,
)
from arm.effects import MAX_ORDER
from arm.measurements import COMPONENTS
from arm.noise import NOISE_MM, NOISE_MRAD, NOISE_PPM, InstrumentNoise, noise_law_problems
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
    "UpdateOptions",
]

Loss = Literal["linear", "huber", "soft_l1"]
OutlierMode = Literal["auto", "keep"]
Solver = Literal["lm", "minpack"]


@dataclass(frozen=True)
class LabOptions:
    """How the lab fits and screens; the same for every entry point. Each field is declared once
    with its range, unit and meaning (``help``: also the text of its command-line option, e.g.
    ``sixaxis lab fit --noise-mm``, which is made from it). The instrument's three fields are the
    quantities of :mod:`arm.noise` (:class:`arm.noise.InstrumentNoise`, docs/format.md): with
    them, or with the rows' own ``std_*`` columns, every row is weighted by its sigma and every
    test compares the residual with it.

    A new option is one field here (its declaration: default, range, help) and the code that
    uses it; the command line of every fitting command (:class:`experiments.cli_inputs.LabArgs`),
    the keywords of the entry points (:class:`OptionFields`, kept alike by a test) and the printed
    next steps follow:

        gate_mm: float | None = declare(None, POSITIVE, help="Leave out rows beyond it (mm).")
    """

    noise_mm: float | None = declare(
        None,
        NOISE_MM,
        help="The noise floor of a 3-D RMS is this times sqrt(3). Refused where the fit's "
        "residual refutes it (more than 3x the noise it shows, beyond chance: a unit slip); 0 "
        "only with --noise-ppm. Default: estimated from the residual.",
    )
    loss: Loss = declare("linear", help="linear (least squares), huber or soft_l1 (robust).")
    outliers: OutlierMode = declare(
        "auto",
        help="auto: leave gross outliers out of the fit and the tests, named by line (a 3-D "
        "residual beyond the radius that Gaussian noise of the robust scale exceeds in 1 % of "
        "clean data sets, once the model and every catalogued effect explain what they can); "
        "keep: fit every pose (duplicates are counted once either way).",
    )
    accept_large: bool = declare(
        False,
        help="Keep a model whose identified parameters exceed the plausible bound of their "
        "kind (10 mm for a DH length error, 50 mrad for a DH angle error, ten times an "
        "effect's typical size) instead of refusing it; base and tool are never bounded.",
    )
    solver: Solver = declare(
        "lm",
        help="For the linear loss: lm (the lab's Levenberg-Marquardt) or minpack (scipy's lmder).",
    )
    f_scale_mm: float | None = declare(
        None, POSITIVE, unit="mm", help="The robust loss's threshold (default 1.345 robust sigmas)."
    )
    max_evaluations: int = declare(
        100, Interval(int, 1, None), help="Evaluations of the model per solve, at most."
    )
    register: bool = declare(
        True,
        help="Place a geometric model's base and tool offsets in closed form before the fit "
        "(--no-register: start from the nominal ones).",
    )
    noise_ppm: float = declare(0.0, NOISE_PPM, help="Rows are weighted by it.")
    noise_mrad: float | None = declare(
        None,
        NOISE_MRAD,
        help="Needed to weigh orientation rows against positions (or std_rx, "
        "std_ry, std_rz columns).",
    )
    min_identified: float = declare(
        1 / 3,
        Interval(float, 0.0, 1.0),
        help="Refuse a campaign whose poses identify less than this share of the parameters "
        "fitted, saying what to measure (one pose identifies 3 of 33; a full campaign about "
        "3/4); 0 fits whatever the poses determine, as an agent's short calibration phase does.",
    )
    measured: tuple[str, ...] | None = declare(
        None,
        help="The components (of x y z rx ry rz) to fit, default every one the data measured "
        "(x, y, z: the positions alone).",
        cli=False,  # the command line's --measured says what the data measured (read with them)
    )

    def __post_init__(self) -> None:
        found = problems(self)
        if not found:
            found = noise_law_problems(self.noise_mm, self.noise_ppm, self.noise_mrad)
        refuse(found, FitError)
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
    min_identified: float
    measured: tuple[str, ...] | None


# the entry points' own settings, declared here so that the command line takes them alike
#: a family-wise rate (diagnose, discover)
ALPHA = Quantity(
    Interval(float, 0.0, 1.0, closed="neither"), help="Family-wise false-alarm rate of the tests"
)
#: the highest order per turn discover scans
ORDER = Quantity(
    Interval(int, 1, MAX_ORDER),
    help="The highest harmonic sin/cos(m*q) per turn scanned on every joint (fewer on a joint "
    "whose sampling resolves fewer: a grid aliases high orders)",
)
#: the report's rounds of diagnose-and-refit
ROUNDS = Quantity(Interval(int, 0, None), help="At most this many rounds of diagnose-and-refit")


@dataclass(frozen=True)
class UpdateOptions:
    """The options of :func:`lab.update.update`, each declared once (:func:`arm.constraints.declare`): the keywords
    of :func:`update` and the options of ``sixaxis lab update``."""

    remount: bool = declare(
        False,
        help="The tool was re-mounted: its offset is fitted on the new poses alone, as the base "
        "is (without it the calibration's tool is the prior).",
    )
    noise_mm: float | None = declare(
        None,
        POSITIVE,
        unit="mm",
        help="The per-axis noise the new poses are weighted by against the prior. Default: the "
        "residual of one session fitted alone, as the calibration states it.",
    )
    # What moves between sessions even where the calibration measured no spread (one session,
    # or sessions that happened to agree): the prior allows at least this much (lab.uncertainty,
    # least_spread)
    rehome_mrad: float = declare(
        2.0,
        NON_NEGATIVE,
        unit="mrad",
        help="The least spread between sessions of each joint's zero offset (a re-homing moves "
        "it by a few mrad): the prior allows this much where the calibration measured less or "
        "none (a calibration of one session).",
    )
    remount_mm: float = declare(
        0.5,
        NON_NEGATIVE,
        unit="mm",
        help="The least spread between sessions of the tool's offset (a tool taken off and put "
        "back): the prior allows this much where the calibration measured less or none. "
        "--remount frees the tool altogether.",
    )


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
    if not ALPHA.constraint.holds(alpha):
        raise FitError(f"alpha must {ALPHA.constraint.predicate}, got {alpha!r}")


#: what `sixaxis lab export --format` writes: a robot TOML, or the arm's URDF with its metrology
#: file beside it (lab.urdf_export)
EXPORT_FORMATS = ("toml", "urdf")
