"""Identification: fit an error model's parameters to measured tool points.

    result = fit(data, robot, "geometric,compliance", validate=other)
    print(result.table())                    # the paper's Table 3, with standard errors
    result.to_dict()                         # the JSON of docs/format.md

The steps, each a pure function of arrays:

1. **Registration.** A large unknown base transform (a laser tracker stands metres away, rotated
   anyhow) and tool offsets (a reflector hundreds of millimetres off the flange) are initialised in
   closed form before any iteration: alternately, Kabsch's rotation of the nominal chain's points
   onto the measured ones (:meth:`scipy.spatial.transform.Rotation.align_vectors`) and linear least
   squares for the base translation and every target's tool offset given that rotation.
2. **Identifiability** (:mod:`lab.identifiability`) on the column-scaled Jacobian at the start:
   parameters that the poses cannot separate are fixed at nominal, not fitted into noise.
3. **Levenberg-Marquardt** on the identifiable parameters, scaled so that every Jacobian column
   has an RMS of 1 m per pose, with the error model's analytic Jacobian:
   :func:`levenberg_marquardt` takes Gauss-Newton steps and damps them (Nielsen's update) only
   when one fails. Once the base is registered these problems are nearly linear, and it converges
   in 3-5 model evaluations where MINPACK's ``lmder`` (``solver="minpack"``, through
   :func:`scipy.optimize.least_squares`), which always starts damped, needs 4-10; both reach the
   same solution (``benchmarks/lab.py``, ``tests/test_lab_fit.py``). A robust loss (``huber``,
   ``soft_l1``) then runs scipy's trust-region reflective method from the linear solution, with
   ``f_scale`` set to 1.345 robust standard deviations of the residual (Huber's 95 %-efficiency
   constant) from the median absolute deviation, re-estimated once.
4. A second identifiability pass at the solution with the noise now known (``noise_mm``, else the
   residual's): a parameter whose typical-size error moves the points by less than the noise is
   fixed too, and a parameter only nearly dependent at the start is restored if the data determine
   it; then a short refit.
5. **Standard errors** from the scaled Jacobian at the solution: ``cov = s^2 (J^T J)^-1`` with
   ``s^2 = sum r^2 / (3N - rank)`` (robust fits: IRLS weights in both).

It is one module, longer than most, because the steps above are one fit: each is short, and
:func:`fit` runs them in this order.
Around these steps (:func:`fit`): rows repeated exactly are counted once, gross outliers are left
out by the stated rule of :mod:`lab.screening` and the model refitted (``outliers="auto"``), and
the identified parameters are checked against the plausible bound of their kind
(:mod:`lab.plausibility`). The model is evaluated block by block (:mod:`lab.blocks`): each step
needs only the small Gram matrix ``J^T J`` and gradient ``J^T r``, and identifiability the R
factor of ``J``, so a whole Jacobian of 200,000 poses is never held.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from arm.description import RobotDescription, as_robot
from arm.effect_api import EffectError, ModelInputs
from arm.effects import Effect, missing_inputs
from arm.errormodel import ErrorModel
from arm.errors import SixAxisError
from arm.kinematics import link_frames
from arm.measurements import MeasurementSet, as_measurements
from arm.params import ROW_FAMILIES, parameter_unit, parse_parameter_name
from arm.so3 import rotation_vector
from lab.blocks import Blocks
from lab.identifiability import Identifiability, analyse_jacobian
from lab.plausibility import Implausible, implausible, likely_cause
from lab.screening import (
    OUTLIER_MODES,
    Duplicate,
    Outlier,
    OutlierScreen,
    annotate,
    candidate_model,
    duplicate_rows,
    duplicates_text,
    explained_residual,
    robust_sigma,
    screen_outliers,
)

__all__ = [
    "LOSSES",
    "OUTLIER_MODES",
    "SCHEMA_VERSION",
    "FitError",
    "FitResult",
    "fit",
    "identifiability_of",
    "reference_values",
    "register_base",
    "robust_sigma",
]

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1
LOSSES = ("linear", "huber", "soft_l1")
# The first pass fits only parameters at least 1 % independent of those before them: nearly
# dependent ones (a tool a fraction of a millimetre off joint 6's axis makes dalpha6 and dd5 so)
# would drift along the near-null space. The second pass, at the solution with the noise known,
# restores every one that the data determine (RANK_TOL and the noise criterion) and refits.
START_TOL = 1e-2
HUBER_K = 1.345  # Huber's tuning constant: 95 % efficiency on Gaussian noise
OUTLIER_RADIUS = math.sqrt(chi2.ppf(0.999, 3))  # 4.03 sigma: the 99.9 % radius of 3-D noise


class FitError(SixAxisError, ValueError):
    """A fit that cannot be done as asked: too few poses, bad options; the message says why."""


# --------------------------------------------------------------------------------------------------
@dataclass
class FitResult:
    """An identified model: parameters with names and standard errors, residuals, metrics.

    ``params`` is the full vector (fixed parameters at nominal) laid out by ``model.layout``;
    ``std`` its standard errors (NaN where fixed); ``residuals`` (N, 3) predicted minus measured
    points. Lengths in m and angles in rad throughout; the ``*_mm`` properties are for people.
    """

    model: ErrorModel
    params: np.ndarray
    std: np.ndarray
    identifiable: np.ndarray
    residuals: np.ndarray
    identifiability: Identifiability
    loss: str
    iterations: int
    evaluations: int
    sigma: float
    initial_rms: float
    inputs: ModelInputs = field(repr=False)
    weights: np.ndarray | None = field(default=None, repr=False)
    validation_residuals: np.ndarray | None = field(default=None, repr=False)
    source: str = "<memory>"
    # what the fit left out of the data given (see lab.screening): ``fitted_rows`` are the
    # indices of the poses fitted (None: all, in order), ``n_rows`` how many the data had
    fitted_rows: np.ndarray | None = field(default=None, repr=False)
    n_rows: int | None = None
    outlier_list: list[Outlier] = field(default_factory=list)
    duplicates: list[Duplicate] = field(default_factory=list)
    outliers_mode: str = "keep"
    screen: OutlierScreen | None = field(default=None, repr=False)
    # parameters beyond the plausible bound of their kind, accepted (fit(accept_large=True))
    implausible: list[Implausible] = field(default_factory=list)

    # -- metrics ---------------------------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        return self.model.layout.names

    @property
    def effects(self) -> list[str]:
        return self.model.effect_names

    @property
    def n_points(self) -> int:
        return int(self.residuals.shape[0])

    @property
    def rank(self) -> int:
        return int(self.identifiable.sum())

    @property
    def n_parameters(self) -> int:
        return len(self.params)

    @property
    def rms(self) -> float:
        """3-D RMS of the fit residuals (m)."""
        return _rms(self.residuals)

    @property
    def rms_mm(self) -> float:
        return 1e3 * self.rms

    @property
    def max_mm(self) -> float:
        return 1e3 * float(np.linalg.norm(self.residuals, axis=1).max())

    @property
    def validation_rms_mm(self) -> float | None:
        r = self.validation_residuals
        return None if r is None else 1e3 * _rms(r)

    @property
    def validation_median_mm(self) -> float | None:
        r = self.validation_residuals
        return None if r is None else 1e3 * float(np.median(np.linalg.norm(r, axis=1)))

    @property
    def sigma_mm(self) -> float:
        """The per-axis noise the residual implies, sqrt(sum r^2 / (3N - rank)), in mm."""
        return 1e3 * self.sigma

    @property
    def condition_number(self) -> float:
        return self.identifiability.condition_number

    @property
    def unidentifiable(self) -> list[str]:
        return self.identifiability.unidentifiable

    @property
    def jacobian(self) -> np.ndarray:
        """The identification Jacobian (N, 3, P) at the solution, computed on demand (it is not
        kept: 200,000 poses of geometric + compliance make 190 MB)."""
        _, J = self.model.predict(self.inputs, self.params, jacobian=True)
        return J

    @property
    def outliers(self) -> np.ndarray:
        """Indices (into the data given to :func:`fit`) of the poses left out as gross outliers
        (``outliers="auto"``; :mod:`lab.screening` states the rule)."""
        return np.array([o.index for o in self.outlier_list], dtype=int)

    @property
    def far_points(self) -> np.ndarray:
        """Indices of fitted points farther off the fit than :data:`OUTLIER_RADIUS` robust
        standard deviations: a point of Gaussian noise lies that far out once in 1,000."""
        r = np.linalg.norm(self.residuals, axis=1)
        return np.flatnonzero(r > OUTLIER_RADIUS * robust_sigma(self.residuals))

    @property
    def outlier_rule(self) -> str | None:
        return None if self.screen is None else self.screen.rule()

    def fitted_data(self, data: MeasurementSet) -> MeasurementSet:
        """The poses of ``data`` (the data given to :func:`fit`) that this fit used."""
        if self.n_rows is not None and len(data) != self.n_rows:
            raise FitError(
                f"{data.source}: {len(data)} rows, but the fit was made on data of {self.n_rows}"
            )
        return data if self.fitted_rows is None else data.subset(self.fitted_rows)

    def parameters(self) -> dict[str, float]:
        return self.model.layout.as_dict(self.params)

    def standard_errors(self) -> dict[str, float | None]:
        return {
            n: (None if np.isnan(s) else float(s))
            for n, s in zip(self.names, self.std, strict=True)
        }

    def __getitem__(self, name: str) -> float:
        return float(self.params[self.model.layout.index(name)])

    # -- use -------------------------------------------------------------------------------------
    def predict(self, data: MeasurementSet | ModelInputs) -> np.ndarray:
        """Predicted tool points (M, 3) of other poses with the identified parameters."""
        inputs = data if isinstance(data, ModelInputs) else _inputs(self.model, data)
        return Blocks(self.model, inputs).predict(self.params)

    def residuals_of(self, data: MeasurementSet) -> np.ndarray:
        """Predicted minus measured points (M, 3) of another measurement set, m."""
        return self.predict(data) - data.xyz

    def validate(self, data: MeasurementSet) -> FitResult:
        """This result with validation metrics on ``data`` (held-out poses)."""
        return replace(self, validation_residuals=self.residuals_of(data))

    def description(self, name: str | None = None) -> RobotDescription:
        """The calibrated arm: a description whose nominal model reproduces this fit."""
        return self.model.description(self.params, name=name)

    # -- tables ----------------------------------------------------------------------------------
    def rows(self) -> list[dict]:
        """One dict per parameter: name, effect, unit, nominal (the described value it
        corrects), error (identified minus nominal), value (nominal + error), std, identifiable;
        SI units."""
        ref = reference_values(self.model)
        err = self.params - self.model.nominal()
        out = []
        for k, n in enumerate(self.names):
            out.append(
                {
                    "name": n,
                    "effect": self.model.layout.effect_of(n),
                    "unit": parameter_unit(n),
                    "nominal": float(ref[k]),
                    "error": float(err[k]),
                    "value": float(ref[k] + err[k]),
                    "std": None if np.isnan(self.std[k]) else float(self.std[k]),
                    "identifiable": bool(self.identifiable[k]),
                }
            )
        return out

    def table(self) -> str:
        """The paper's Table 3 and more: per parameter its nominal value, the identified error and
        its standard error (lengths in mm; angles: nominal in deg, errors in mrad)."""
        lines = [
            f"{'parameter':<10} {'nominal':>14} {'error':>12} {'std':>10}  unit",
        ]
        for row in self.rows():
            unit = row["unit"]
            if unit == "m":
                nom, f, shown = row["nominal"] * 1e3, 1e3, "mm"
                nom_s = f"{nom:.3f} mm"
            elif unit == "rad":
                nom_s = f"{math.degrees(row['nominal']):.3f} deg"
                f, shown = 1e3, "mrad"
            else:
                nom_s = f"{row['nominal']:.4g}"
                f, shown = 1.0, unit
            if row["identifiable"]:
                err_s = f"{row['error'] * f:+.4g}"
                std_s = f"{row['std'] * f:.2g}" if row["std"] is not None else "-"
            else:
                err_s, std_s = "fixed", ""
            lines.append(f"{row['name']:<10} {nom_s:>14} {err_s:>12} {std_s:>10}  {shown}")
        return "\n".join(lines)

    def summary(self) -> str:
        out = [
            f"fit of {', '.join(self.effects)} to {self.n_points} points ({self.loss} loss): "
            f"RMS {self.initial_rms * 1e3:.4f} mm -> {self.rms_mm:.4f} mm, max {self.max_mm:.4f} mm, "
            f"{self.iterations} iterations"
        ]
        if self.validation_residuals is not None:
            out.append(
                f"validation on {len(self.validation_residuals)} points: RMS "
                f"{self.validation_rms_mm:.4f} mm, median {self.validation_median_mm:.4f} mm"
            )
        out.append(self.identifiability.summary())
        out += self.screening_lines()
        return "\n".join(out)

    def screening_lines(self, limit: int = 10) -> list[str]:
        """What was left out of the fit and why, for people: duplicates, outliers."""
        out = []
        if self.duplicates:
            out.append(
                f"{len(self.duplicates)} duplicate row(s) counted once: "
                f"{duplicates_text(self.duplicates)} (a copy of a measurement is not a second one)"
            )
        if self.outlier_list:
            shown = ", ".join(
                f"{o.where} ({o.residual_mm:.3g} mm{'; ' + o.note if o.note else ''})"
                for o in self.outlier_list[:limit]
            )
            more = (
                f", ... {len(self.outlier_list) - limit} more"
                if len(self.outlier_list) > limit
                else ""
            )
            out.append(
                f"{len(self.outlier_list)} outlier(s) left out of the fit: {shown}{more}; rule: "
                f"{self.outlier_rule} (--outliers keep fits them)"
            )
        elif self.screen is not None and self.screen.note:
            out.append(f"outliers: {self.screen.note}")
        if self.implausible:
            out.append(
                "accepted beyond the plausible bound of their kind: "
                + "; ".join(b.text() for b in self.implausible)
            )
        return out

    def to_dict(self) -> dict:
        """The JSON object of ``sixaxis lab fit --json`` (docs/format.md, fit)."""
        ident = self.identifiability
        return {
            "schema_version": SCHEMA_VERSION,
            "effects": self.effects,
            "n_points": self.n_points,
            "rms_mm": self.rms_mm,
            "max_mm": self.max_mm,
            "validation_rms_mm": self.validation_rms_mm,
            "validation_median_mm": self.validation_median_mm,
            "parameters": self.parameters(),
            "std": self.standard_errors(),
            "rank": self.rank,
            "n_parameters": self.n_parameters,
            "unidentifiable": self.unidentifiable,
            "condition_number": _finite(self.condition_number),
            "o1": ident.o1,
            "o4": ident.o4,
            "identifiable": [n for n, ok in zip(self.names, self.identifiable, strict=True) if ok],
            "sigma_mm": self.sigma_mm,
            "initial_rms_mm": 1e3 * self.initial_rms,
            "loss": self.loss,
            "iterations": self.iterations,
            "robot": self.model.robot.name,
            "targets": list(self.model.targets),
            "source": self.source,
            "n_rows": self.n_points if self.n_rows is None else self.n_rows,
            "outliers_mode": self.outliers_mode,
            "outliers": [o.to_dict() for o in self.outlier_list],
            "outlier_rule": self.outlier_rule,
            "duplicates": [d.to_dict() for d in self.duplicates],
            "implausible": [b.to_dict() for b in self.implausible],
        }


def _rms(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(np.asarray(r) ** 2, axis=1)))) if len(r) else float("nan")


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


# --------------------------------------------------------------------------------------------------
def reference_values(model: ErrorModel) -> np.ndarray:
    """The described quantity each parameter corrects (alpha_{i-1} for ``dalpha{i}``, the tool
    point coordinate for ``tx``, the base value for ``bx``...), so value = reference + error."""
    rob = model.robot
    tp = rob.tool_points  # target k takes tool k of the description, else the first
    tools = np.array([tp[k] if k < len(tp) else tp[0] for k in range(len(model.targets))])
    nominal = model.nominal()
    out = np.zeros(len(model.layout))
    fields = dict(zip(ROW_FAMILIES, ("alpha", "a", "theta_offset", "d"), strict=True))
    geo = (
        set(model.layout.names[model.layout.slice("geometric")])
        if ("geometric" in model.layout.effects)
        else set()
    )
    for k, n in enumerate(model.layout.names):
        p = parse_parameter_name(n) if n in geo else None
        if p is not None and p.kind == "row" and p.number is not None:
            out[k] = getattr(rob.joints[p.number - 1], fields[p.family])
        elif p is not None and p.kind == "beta" and p.number is not None:
            out[k] = rob.joints[p.number].beta
        elif p is not None and p.kind == "tool":
            idx = p.number if p.number is not None else model.targets[0]
            out[k] = tools[model.targets.index(idx), "xyz".index(p.family[1])]
        else:  # the base, and every other effect: the parameter is the value itself
            out[k] = nominal[k]
    return out


def _inputs(model: ErrorModel, data: MeasurementSet) -> ModelInputs:
    try:
        return model.inputs(data.q, data.columns, source=data.source)
    except EffectError as exc:
        raise FitError(str(exc)) from None


def build_model(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: str | Sequence[str | Effect],
) -> tuple[ErrorModel, ModelInputs]:
    """The error model for these data (one tool offset per target) and its inputs."""
    try:
        model = ErrorModel(robot, effects, targets=data.targets)
    except EffectError as exc:
        raise FitError(str(exc)) from None
    for e in model.effects:
        why = missing_inputs(e, model.robot, list(data.columns))
        if why:
            raise FitError(f"{data.source}: {e.label} cannot be fitted without {why}")
    inputs = _inputs(model, data)
    n, P = len(data), len(model.layout)
    if 3 * n <= P:
        need = P // 3 + 1
        raise FitError(
            f"{data.source}: {n} poses give {3 * n} equations, not more than the {P} parameters "
            f"of {','.join(model.effect_names)}; at least {need} poses are needed"
        )
    return model, inputs


# --------------------------------------------------------------------------------------------------
def register_base(
    model: ErrorModel,
    inputs: ModelInputs,
    xyz: np.ndarray,
    params: np.ndarray,
    tools: bool = True,
    iterations: int = 100,
) -> np.ndarray:
    """Closed-form initial base transform (and tool offsets) for a geometric model.

    Alternates Kabsch's rotation of the chain's points onto ``xyz`` and linear least squares for
    the base translation and each target's tool point given the rotation; each step lowers the sum
    of squares, so it converges from a tool hundreds of millimetres off. Returns ``params`` with the
    base (and tool) parameters replaced."""
    lay = model.layout
    p = np.array(params, dtype=float)
    st = model.state(inputs, p)
    # the last frame of every pose, block by block (all seven frames of 200k poses: 130 MB)
    o6, R6 = np.empty((inputs.n, 3)), np.empty((inputs.n, 3, 3))
    for sl, part in Blocks(model, inputs):
        st_b = model.state(part, p)
        f = link_frames(st_b.chain, model.joint_angles(part, p))
        o6[sl], R6[sl] = f.o[:, 6], f.R[:, 6]
    tool = st.tools.copy()
    tgt = inputs.target
    n, K = inputs.n, len(model.targets)
    rows = np.arange(n)
    R = st.base_R
    t = st.base_t
    for _ in range(iterations):
        pts = o6 + np.einsum("nij,nj->ni", R6, tool[tgt])
        pc, mc = pts.mean(axis=0), xyz.mean(axis=0)
        rot, _ = Rotation.align_vectors(xyz - mc, pts - pc)
        R = rot.as_matrix()
        t = mc - R @ pc
        if not tools:
            break
        # xyz - R o6 = R R6 tool[target] + t, linear in (t, tools)
        A = np.zeros((n, 3, 3 + 3 * K))
        A[:, :, :3] = np.eye(3)
        RR6 = np.einsum("ij,njk->nik", R, R6)
        for k in range(K):
            A[rows[tgt == k], :, 3 + 3 * k : 6 + 3 * k] = RR6[tgt == k]
        b = xyz - o6 @ R.T
        # solve for the change from the current tools so that unseen directions stay put
        b = b - np.einsum("nij,nj->ni", RR6, tool[tgt])
        A2 = A.reshape(-1, 3 + 3 * K)
        sol, *_ = np.linalg.lstsq(A2.T @ A2, A2.T @ b.reshape(-1), rcond=None)
        t = sol[:3]
        step = sol[3:].reshape(K, 3)
        tool = tool + step
        if np.max(np.abs(step)) < 1e-10:
            break
    names = lay.names
    geo = lay.slice("geometric")
    for name, v in zip(("bx", "by", "bz"), t, strict=True):
        p[lay.index(name)] = v
    for name, v in zip(("brx", "bry", "brz"), rotation_vector(R), strict=True):
        p[lay.index(name)] = v
    if tools:
        tool_names = [x for x in names[geo] if x[:1] == "t" and x[1:2] in ("x", "y", "z")]
        idx = lay.indices(tool_names).reshape(K, 3)
        p[idx] += tool - st.tools
    return p


# --------------------------------------------------------------------------------------------------
class _Problem:
    """The scaled least-squares problem on the free parameters, evaluated block by block
    (:class:`lab.blocks.Blocks`): an evaluation gives the residual (3N) and the Gram matrix and
    gradient of the scaled Jacobian of the free parameters, never the whole Jacobian."""

    def __init__(self, blocks: Blocks, xyz, p0, free, scale):
        self.blocks, self.xyz = blocks, xyz
        self.p0 = p0
        self.idx = np.flatnonzero(free)
        self.s = scale[self.idx]
        self._u: np.ndarray | None = None
        self._r, self._G, self._g = np.empty(0), np.empty((0, 0)), np.empty(0)
        self._J: np.ndarray | None = None  # the whole Jacobian, kept when there is one block

    def params(self, u: np.ndarray) -> np.ndarray:
        p = self.p0.copy()
        p[self.idx] += u * self.s
        return p

    def evaluate(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r (3N), G = A^T A, g = A^T r) at ``u``, A the scaled Jacobian of the free columns."""
        if self._u is not None and np.array_equal(self._u, u):
            return self._r, self._G, self._g
        p = self.params(u)
        k = self.idx.size
        r = np.empty(3 * self.blocks.n)
        G, g = np.zeros((k, k)), np.zeros(k)
        for sl, pred, J in self.blocks.jacobians(p):
            rb = (pred - self.xyz[sl]).reshape(-1)
            A = J[:, :, self.idx].reshape(-1, k) * self.s
            if self.blocks.single:
                G, g = A.T @ A, A.T @ rb
                self._J = J
            else:
                G += A.T @ A
                g += A.T @ rb
            r[3 * sl.start : 3 * sl.stop] = rb
        self._u, self._r, self._G, self._g = u.copy(), r, G, g
        return r, G, g

    def fun(self, u: np.ndarray) -> np.ndarray:
        return self.evaluate(u)[0]

    def jac(self, u: np.ndarray) -> np.ndarray:
        """The whole scaled Jacobian (3N, k), for scipy's solvers (MINPACK, robust losses)."""
        p = self.params(u)
        k = self.idx.size
        out = np.empty((3 * self.blocks.n, k))
        for sl, _, J in self.blocks.jacobians(p):
            out[3 * sl.start : 3 * sl.stop] = J[:, :, self.idx].reshape(-1, k) * self.s
        return out


def levenberg_marquardt(
    evaluate: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]],
    u0: np.ndarray,
    max_evaluations: int = 200,
    ftol: float = 1e-10,
) -> tuple[np.ndarray, int, int]:
    """Minimise ``|r(u)|^2`` from ``u0``: Gauss-Newton steps, damped (Marquardt's diagonal
    scaling) only when a step fails to lower the sum of squares.

    ``evaluate(u)`` returns the residual ``r``, the Gram matrix ``G = A^T A`` and the gradient
    ``g = A^T r`` of the Jacobian ``A`` at ``u`` (summed block by block: the tall ``A`` is never
    needed). For well-scaled, nearly linear problems (a calibration after registration) this
    takes 2-4 evaluations where MINPACK's ``lmder``, which always starts damped, takes 7-10; every
    evaluation here costs a full Jacobian. Steps come from the normal equations of the small
    (P, P) Gram matrix: ``(G + lam diag G) du = -g`` (the columns are scaled and the identifiable
    ones well conditioned). Stops when a step would lower the sum of squares by less than
    ``ftol`` of itself. Returns ``(u, iterations, evaluations)``.
    """
    u = np.array(u0, dtype=float)
    r, G, g = evaluate(u)
    cost = float(r @ r)
    lam, nu, nfev, it = 0.0, 2.0, 1, 0
    while nfev < max_evaluations:
        d = np.maximum(np.diag(G), 1e-12 * max(float(np.max(np.diag(G), initial=0.0)), 1.0))
        while True:
            try:
                cf = cho_factor(G + lam * np.diag(d))
                step = -cho_solve(cf, g)
            except np.linalg.LinAlgError:
                lam = max(10 * lam, 1e-8)
                continue
            predicted = -(2.0 * g @ step + step @ G @ step)
            if predicted <= ftol * cost or nfev >= max_evaluations:
                return u, it, nfev
            r_new, G_new, g_new = evaluate(u + step)
            nfev += 1
            cost_new = float(r_new @ r_new)
            if cost_new < cost:
                rho = (cost - cost_new) / predicted
                u, r, G, g = u + step, r_new, G_new, g_new
                cost = cost_new
                it += 1
                # Nielsen's update: a good model lowers the damping smoothly; GN stays GN
                if lam > 0.0:
                    lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                break
            lam = 1e-4 if lam == 0.0 else lam * nu
            nu *= 2.0
    log.warning("the fit stopped after %d evaluations without converging", nfev)
    return u, it, nfev


@dataclass(frozen=True)
class _Solution:
    params: np.ndarray
    residuals: np.ndarray  # (N, 3)
    gram: np.ndarray  # A^T A of the scaled free columns at params
    scale: np.ndarray  # the scale of those columns
    jacobian: np.ndarray | None  # (N, 3, P) at params, when the data are one block
    iterations: int
    evaluations: int


def _solve(blocks, xyz, p0, free, scale, loss, f_scale, max_nfev, solver="lm"):
    prob = _Problem(blocks, xyz, p0, free, scale)
    u0 = np.zeros(prob.idx.size)
    if loss == "linear" and solver == "lm":
        u, it, nfev = levenberg_marquardt(prob.evaluate, u0, max_nfev)
    else:
        kw = dict(x_scale=1.0, max_nfev=max_nfev)
        if loss == "linear":  # MINPACK's lmder, kept for comparison (benchmarks/lab.py)
            res = least_squares(prob.fun, u0, jac=prob.jac, method="lm", **kw)
        else:
            res = least_squares(
                prob.fun, u0, jac=prob.jac, method="trf", loss=loss, f_scale=f_scale, **kw
            )
        if res.status <= 0:
            log.warning("the fit did not converge: %s", res.message)
        u, it, nfev = res.x, int(res.njev or 0), int(res.nfev)
    r, G, _ = prob.evaluate(u)
    J = prob._J if blocks.single else None
    return _Solution(prob.params(u), r.reshape(-1, 3), G, scale, J, it, nfev)


def _weights(r: np.ndarray, loss: str, f_scale: float) -> np.ndarray:
    """IRLS weights rho'(z) of scipy's losses at residual components ``r``."""
    z = (np.asarray(r) / f_scale) ** 2
    if loss == "huber":
        return np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0)))
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1.0 + z)
    return np.ones_like(z)


IMPLAUSIBLE_RMS = 0.1  # m: after a fit, no real arm's model is this far from most measurements


def fit(
    data: MeasurementSet | str | Path,
    robot: RobotDescription | str | Path | None = None,
    effects: str | Sequence[str | Effect] = "geometric",
    loss: str = "linear",
    validate: MeasurementSet | str | Path | None = None,
    *,
    noise_mm: float | None = None,
    f_scale_mm: float | None = None,
    start: Mapping[str, float] | None = None,
    fixed: Iterable[str] = (),
    register: bool = True,
    max_evaluations: int = 100,
    solver: str = "lm",
    outliers: str = "auto",
    accept_large: bool = False,
) -> FitResult:
    """Identify ``effects`` of ``robot`` (default the seed arm) from ``data``.

    ``loss``: ``linear`` (Levenberg-Marquardt), ``huber`` or ``soft_l1`` (robust to outliers).
    ``validate``: held-out measurements for validation RMS and median. ``noise_mm``: the
    instrument's per-axis standard uncertainty, if known (else estimated from the residual).
    ``f_scale_mm``: the robust loss's threshold (default 1.345 robust sigmas). ``start``: starting
    values by name; ``fixed``: names to hold at their starting value. ``register``: initialise a
    geometric model's base and tool offsets in closed form first. ``solver``: ``lm`` (this
    module's Levenberg-Marquardt) or ``minpack`` (scipy's ``lmder``), for linear loss.
    ``outliers``: ``auto`` leaves gross outliers out by the rule of :mod:`lab.screening` (the
    result names them, ``result.outlier_list``), ``keep`` fits every pose. Rows repeated exactly
    are counted once either way (``result.duplicates``). ``accept_large``: keep a
    model whose identified parameters exceed the plausible bound of their kind
    (:mod:`lab.plausibility`; listed in ``result.implausible``) instead of refusing it.
    """
    if loss not in LOSSES:
        raise FitError(f"loss must be one of {', '.join(LOSSES)}, got {loss!r}")
    if solver not in ("lm", "minpack"):
        raise FitError(f"solver must be 'lm' or 'minpack', got {solver!r}")
    if outliers not in OUTLIER_MODES:
        raise FitError(f"outliers must be one of {', '.join(OUTLIER_MODES)}, got {outliers!r}")
    data = as_measurements(data)
    robot = as_robot(robot)

    def fit_points(d: MeasurementSet) -> FitResult:
        return _fit_points(
            d,
            robot,
            effects,
            loss,
            noise_mm=noise_mm,
            f_scale_mm=f_scale_mm,
            start=start,
            fixed=fixed,
            register=register,
            max_evaluations=max_evaluations,
            solver=solver,
        )

    distinct, dups = duplicate_rows(data)
    if dups:
        log.warning(
            "%s: %d row(s) repeat an earlier row exactly: %s; each is counted once",
            data.source,
            len(dups),
            duplicates_text(dups),
        )
        unique = data.subset(distinct)
    else:
        unique = data
    try:
        result = fit_points(unique)
    except FitError as exc:
        if dups:
            raise FitError(f"{exc} ({len(dups)} duplicate row(s) counted once)") from None
        raise
    screen = None
    if outliers == "auto":
        result, screen = screen_outliers(
            unique,
            result,
            refit=lambda keep: fit_points(unique.subset(keep)),
            residuals=lambda r: r.residuals_of(unique),
            rank=lambda r: r.rank,
            explain=lambda r, keep: _explain_with_candidates(r, unique, keep),
        )
        kept = distinct[screen.keep]
        found = [replace(o, index=int(distinct[o.index])) for o in screen.outliers]
        found = annotate(found, result.model, data)
        if found:
            log.warning(
                "%s: %d outlier(s) left out of the fit (%s)",
                data.source,
                len(found),
                ", ".join(o.where for o in found[:5]),
            )
    else:
        kept, found = distinct, []
    bad = _check_plausible(result, accept_large)
    result = replace(
        result,
        implausible=bad,
        fitted_rows=None if len(kept) == len(data) else kept,
        n_rows=len(data),
        outlier_list=found,
        duplicates=dups,
        outliers_mode=outliers,
        screen=screen,
        source=data.source,
    )
    if validate is not None:
        result = result.validate(as_measurements(validate))
    log.info("%s", result.summary())
    return result


def _check_plausible(result: FitResult, accept: bool) -> list[Implausible]:
    """The identified parameters beyond the plausible bound of their kind: an error naming them
    and the likely cause, unless ``accept`` (then logged and returned)."""
    bad = implausible(result.model, result.params, result.identifiable)
    if not bad:
        return bad
    shown = "; ".join(b.text() for b in bad[:4])
    if len(bad) > 4:
        shown += f"; and {len(bad) - 4} more"
    cause = likely_cause(result.model, bad)
    if not accept:
        raise FitError(
            f"{result.source}: not a plausible model of {result.model.robot.name!r}: {shown}, "
            f"beyond the bound of its kind; likely cause: {cause}. Check the data and the "
            "arm's file, or keep it anyway with --accept-large (accept_large=True)"
        )
    log.warning("%s: accepted beyond the plausible bound: %s (%s)", result.source, shown, cause)
    return bad


def _explain_with_candidates(
    res: FitResult, data: MeasurementSet, keep: np.ndarray
) -> tuple[np.ndarray, int]:
    """The residual (N, 3) of every pose of ``data`` that is left once the model's parameters
    *and every candidate effect* (:func:`lab.screening.candidate_model`) have explained what
    they can, to first order, on the poses of ``keep``; and the number of columns fitted."""
    try:
        full, _ = candidate_model(res.model, data)
    except EffectError:  # a user's effect that cannot be built here: the model alone
        full = res.model
    p = full.nominal()
    p[full.layout.indices(res.model.layout.names)] = res.params
    blocks = Blocks(full, _inputs(full, data))
    e = (blocks.predict(p) - data.xyz).reshape(-1)  # the model's residual: candidates are zero

    def columns():
        for sl, _, J in blocks.jacobians(p, keep_cache=False):
            yield slice(3 * sl.start, 3 * sl.stop), J.reshape(-1, J.shape[2])

    r, k = explained_residual(e, columns, np.repeat(keep, 3).astype(float))
    return r.reshape(-1, 3), k


def _fit_points(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: str | Sequence[str | Effect],
    loss: str,
    *,
    noise_mm: float | None,
    f_scale_mm: float | None,
    start: Mapping[str, float] | None,
    fixed: Iterable[str],
    register: bool,
    max_evaluations: int,
    solver: str,
) -> FitResult:
    """The fit of every pose of ``data``: registration, identifiability, Levenberg-Marquardt,
    identifiability again with the noise known, standard errors (the module docstring)."""
    model, inputs = build_model(data, robot, effects)
    lay = model.layout
    xyz = data.xyz
    p = model.nominal()
    if start:
        p = lay.vector(start, default=p)
    held = np.zeros(len(lay), dtype=bool)
    for n in fixed:
        held[lay.index(n)] = True

    if register and "geometric" in lay.effects:
        before = _rms(model.predict(inputs, p) - xyz)
        p_reg = register_base(model, inputs, xyz, p, tools=not held[_tool_idx(model)].any())
        p_reg[held] = p[held]  # a held base keeps the value given: registration is a start only
        after = _rms(model.predict(inputs, p_reg) - xyz)
        if after < before:
            log.debug("registration: RMS %.4g mm -> %.4g mm", before * 1e3, after * 1e3)
            p = p_reg

    blocks = Blocks(model, inputs)

    def solve(p, free, scale, loss="linear", f_scale=1.0):
        return _solve(blocks, xyz, p, free, scale, loss, f_scale, max_evaluations, solver)

    def identifiability(p, J, **kw):
        """At ``p``: from the whole Jacobian ``J`` when there is one block, else from the R of
        its QR decomposition (the same inner products, :mod:`lab.blocks`); held parameters'
        columns zeroed."""
        if J is None:
            R = _without(blocks.r_factor(p), held)
            return analyse_jacobian(model, R, n_poses=blocks.n, **kw)
        return analyse_jacobian(model, _without(J, held), **kw)

    # identifiability at the start (the structure), fit, again with the noise known, refit
    if blocks.single:
        pred, J = model.predict(inputs, p, jacobian=True)
    else:
        pred, J = blocks.predict(p), None
    initial_rms = _rms(pred - xyz)
    # held parameters are known: the others' identifiability is judged without their columns
    # (with the base held, row 1 is identifiable; with it free, the base absorbs row 1)
    ident = identifiability(p, J, tol=START_TOL, warn=False)
    del J
    _check_effects_identifiable(model, ident, held, data.source)
    free = ident.identifiable & ~held
    sol = solve(p, free, ident.scale)
    iterations, evaluations = sol.iterations, sol.evaluations
    if loss == "linear":
        sigma = float(np.sqrt(np.sum(sol.residuals**2) / max(sol.residuals.size - free.sum(), 1)))
    else:
        sigma = robust_sigma(sol.residuals)
    # the median pose, not the RMS: a few gross outliers must not condemn the model
    typical_miss = float(np.median(np.linalg.norm(sol.residuals, axis=1)))
    if typical_miss > IMPLAUSIBLE_RMS:
        raise FitError(
            f"{data.source}: the model cannot follow these measurements (RMS "
            f"{_rms(sol.residuals) * 1e3:.4g} mm, median {typical_miss * 1e3:.4g} mm after fitting "
            f"{', '.join(lay.effects)}); are they in other units (length in mm, angles in deg: "
            "say so when reading) or of another robot?"
        )
    if noise_mm is not None:
        noise = noise_mm * 1e-3
    else:  # the residual's, unless a few gross errors inflate it (then its robust scale)
        rs = robust_sigma(sol.residuals)
        noise = sigma if sigma <= 3.0 * rs else rs
    ident = identifiability(sol.params, sol.jacobian, noise=noise, warn=True)
    if held.any():
        ident = replace(ident, held=tuple(np.asarray(lay.names)[held]))
    free2 = ident.identifiable & ~held
    if not free2.any():
        raise FitError(
            f"{data.source}: no parameter of {', '.join(lay.effects)} can be identified from these"
            f" {len(xyz)} poses at a noise of {noise * 1e3:.3g} mm"
        )
    if not np.array_equal(free2, free):
        free = free2
        sol = solve(np.where(free | held, sol.params, p), free, ident.scale)
        iterations, evaluations = iterations + sol.iterations, evaluations + sol.evaluations
    f_scale = None
    if loss != "linear":
        f_scale = f_scale_mm * 1e-3 if f_scale_mm else HUBER_K * sigma
        for _ in range(1 if f_scale_mm else 2):  # re-estimate the scale once, robustly
            sol = solve(sol.params, free, ident.scale, loss, f_scale)
            iterations, evaluations = iterations + sol.iterations, evaluations + sol.evaluations
            if not f_scale_mm:
                f_scale = HUBER_K * robust_sigma(sol.residuals)

    r = sol.residuals
    w = _weights(r, loss, f_scale) if f_scale is not None else None
    gram, scale = sol.gram, sol.scale  # the Gram matrix of the columns as scaled in the solve
    if w is not None:  # the robust fit's IRLS weights in the Gram matrix
        gram = _weighted_gram(blocks, sol.params, free, scale, w)
    std, sigma = _standard_errors(gram, r, free, scale, w)
    result = FitResult(
        model=model,
        params=sol.params,
        std=std,
        identifiable=free,
        residuals=r,
        identifiability=ident,
        loss=loss,
        iterations=iterations,
        evaluations=evaluations,
        sigma=sigma,
        initial_rms=initial_rms,
        inputs=inputs,
        weights=w,
        source=data.source,
    )
    return result


def _check_effects_identifiable(
    model: ErrorModel, ident: Identifiability, held: np.ndarray, source: str
) -> None:
    """An effect asked for whose every parameter the data cannot identify (a constant column,
    a joint that gravity never loads) is an error, not parameters quietly held at nominal."""
    lay = model.layout
    for e in model.effects:
        if e.name == "geometric":
            continue
        sl = lay.slice(e.name)
        if (ident.identifiable[sl] | held[sl]).any():
            continue
        names = lay.names[sl]
        moves = [n for n in names if ident.combinations.get(n)]
        why = (
            "they move no measured point with these data"
            if not moves
            else "they move the points only as other parameters do ("
            + "; ".join(ident.labels[n] for n in moves[:4])
            + ")"
        )
        raise FitError(
            f"{source}: {e.label} cannot be fitted from these data: none of its parameters "
            f"({', '.join(names)}) is identifiable; {why}"
        )


def _without(J: np.ndarray, held: np.ndarray) -> np.ndarray:
    """``J`` with the columns of held (known) parameters zeroed (the last axis: a Jacobian
    (N, 3, P) or the R factor (P, P) of one, whose inner products are the same)."""
    if not held.any():
        return J
    J = J.copy()
    J[..., held] = 0.0
    return J


def _tool_idx(model: ErrorModel) -> np.ndarray:
    names = model.layout.names[model.layout.slice("geometric")]
    return model.layout.indices([n for n in names if n[:1] == "t" and n[1:2] in ("x", "y", "z")])


def _weighted_gram(blocks: Blocks, p, free, scale, w) -> np.ndarray:
    """``A^T W A`` of the scaled free columns at ``p``, W the IRLS weights (N, 3)."""
    idx = np.flatnonzero(free)
    G = np.zeros((idx.size, idx.size))
    for sl, _, J in blocks.jacobians(p):
        A = J[:, :, idx].reshape(-1, idx.size) * scale[idx]
        A = A * np.sqrt(w[sl].reshape(-1))[:, None]
        G += A.T @ A
    return G


def _standard_errors(G, r, free, scale, w=None) -> tuple[np.ndarray, float]:
    """Standard errors from the Gram matrix ``G`` of the scaled free columns (weighted for a
    robust fit): ``cov = s^2 G^-1``, ``s^2 = sum w r^2 / (3N - rank)``."""
    idx = np.flatnonzero(free)
    rr = r.reshape(-1)
    if w is not None:
        rr = rr * np.sqrt(w.reshape(-1))
    dof = max(rr.size - idx.size, 1)
    sigma = float(np.sqrt(rr @ rr / dof))
    std = np.full(len(free), np.nan)
    if idx.size:
        try:
            cov = cho_solve(cho_factor(G), np.eye(idx.size))
        except np.linalg.LinAlgError:  # singular where the fit stopped: nothing is determined
            log.warning(
                "the parameters are not determined where the fit stopped (singular "
                "Gram matrix): their standard errors are infinite"
            )
            cov = np.diag(np.full(idx.size, np.inf))
        std[idx] = sigma * np.sqrt(np.diag(cov)) * scale[idx]
    return std, sigma


def identifiability_of(
    data: MeasurementSet | str | Path | np.ndarray,
    robot: RobotDescription | str | Path | None = None,
    effects: str | Sequence[str | Effect] = "geometric",
    params: Mapping[str, float] | None = None,
    *,
    noise_mm: float | None = None,
) -> Identifiability:
    """Which parameters of ``effects`` the poses of ``data`` (a measurement set, or joint angles
    (N, 6) alone) can identify, at ``params`` (default nominal): rank, named unidentifiable
    combinations, condition number, O1 and O4. With ``noise_mm`` parameters whose typical-size
    error moves the points by less than the noise are counted unidentifiable too."""
    robot = as_robot(robot)
    if isinstance(data, np.ndarray):
        data = MeasurementSet(data, np.zeros((len(np.atleast_2d(data)), 3)), source="poses")
    data = as_measurements(data)
    try:
        model = ErrorModel(robot, effects, targets=data.targets)
    except EffectError as exc:
        raise FitError(str(exc)) from None
    for e in model.effects:
        why = missing_inputs(e, model.robot, list(data.columns))
        if why:
            raise FitError(f"{data.source}: {e.label} cannot be fitted without {why}")
    inputs = _inputs(model, data)
    p = model.nominal() if not params else model.layout.vector(params, default=model.nominal())
    _, J = model.predict(inputs, p, jacobian=True)
    return analyse_jacobian(model, J, noise=None if noise_mm is None else noise_mm * 1e-3)
