"""Online calibration: recursive least squares over the identifiable parameters of an error model.

As tracker measurements arrive during tracking, :class:`RecursiveLeastSquares` updates the
parameter vector that the MPC's model uses. It learns what its :class:`~arm.errormodel.ErrorModel`
can express: ``effects="geometric,compliance"`` lets it learn the joint stiffnesses too.

The estimator is an information-form Gauss-Newton filter with *regularised* exponential forgetting
(Kulhavy's stabilised forgetting): each update

    Lambda <- lam Lambda + (1 - lam) Lambda0 + H' R^-1 H
    z      <- z + Lambda^-1 (H' R^-1 e - (1 - lam) Lambda0 z)

in parameters scaled by their typical magnitudes (``z = (p - p0) / s``, prior ``Lambda0 = I``), the
measurement Jacobian ``H`` and innovation ``e = y - f(q, p)`` evaluated at the current estimate.
Old information fades with ``lam`` (so a slowly changing arm is followed) but never below the prior,
so directions that the current motion does not excite do not wind up.

Only parameters found identifiable are estimated (:func:`identifiable_parameters`: the lab's
analysis of the column-scaled identification Jacobian over random poses, or a local QR with column
pivoting without the lab); the rest stay at their nominal values, as the lab fixes them. It
survives:

* dropouts: no measurement, no update;
* latency: the update uses the encoder reading taken when the point was sampled
  (``info["measurement_q"]``), not the current one;
* outliers: innovation gating. A measurement is rejected when its normalised innovation is beyond
  a chi-square gate *and* far above the recent typical innovation (so that an unmodelled effect,
  which makes every innovation large, does not lock the estimator out); after a run of rejections
  the next one is accepted anyway (a real change of the arm, e.g. a payload).

It is one module, longer than most, because the estimator, the choice of what it may estimate and
the buffer of measurements it widens its model over share the scaled parameter vector.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Mapping, Sequence

import casadi as ca
import numpy as np
import scipy.linalg
from scipy.linalg import lapack

from agents.base import refuse_settings
from agents.errors import AgentError
from agents.tool_model import BufferedFunction, ToolModel
from arm.constraints import POSITIVE, Constraint, Interval
from arm.effects import Effect, parse_effects, union_of
from arm.errormodel import ErrorModel
from arm.kinematics import gravity_torques
from arm.measurements import MeasurementSet
from arm.sampling import sample_poses

__all__ = [
    "MeasurementBuffer",
    "RecursiveLeastSquares",
    "cached_identifiable",
    "identifiable_parameters",
    "merge_effects",
    "prior_scales",
    "qr_identifiable",
    "random_columns",
]

log = logging.getLogger(__name__)

#: what the estimators' settings may be (:mod:`arm.constraints`): the measurement noise (m, per
#: axis) and the forgetting factor (1: remember everything); the buffer's capacity in points
ESTIMATOR_SETTINGS: dict[str, Constraint] = {
    "sigma": POSITIVE,
    "forgetting": Interval(float, 0.0, 1.0, closed="right"),
}
BUFFER_SETTINGS: dict[str, Constraint] = {"capacity": Interval(int, 1, None)}

_I3 = np.eye(3)

#: chi-square(3) quantile for p = 1e-5: a Gaussian innovation is rejected once in 100,000
CHI2_3_GATE = 25.9


def prior_scales(model: ErrorModel) -> np.ndarray:
    """A typical magnitude of each parameter's error (its effect's ``typical`` range, upper end);
    parameters of effects without one get 1e-3."""
    s = np.full(len(model.layout), 1e-3)
    for e in model.effects:
        sl = model.layout.slice(e.name)
        for k, name in zip(range(sl.start, sl.stop), model.layout.names[sl], strict=True):
            rg = e.typical_range(name)
            if rg is not None:
                s[k] = rg[1]
    return s


def random_columns(model: ErrorModel, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Plausible per-pose columns for an identifiability study: temperature 15-45 degC, random
    motion directions, the description's payload."""
    need = model.required_columns() | {"payload"}
    cols: dict[str, np.ndarray] = {}
    for c in sorted(need):
        if c == "temperature":
            cols[c] = rng.uniform(15.0, 45.0, n)
        elif c.startswith("dir"):
            cols[c] = rng.choice((-1.0, 1.0), n)
        elif c == "payload":
            cols[c] = np.full(n, float(model.robot.payload))
        else:
            cols[c] = np.zeros(n)
    return cols


def identifiable_parameters(
    model: ErrorModel,
    q: np.ndarray | None = None,
    columns: Mapping[str, np.ndarray] | None = None,
    p: np.ndarray | None = None,
    noise: float | None = None,
    n_poses: int = 200,
    seed: int = 0,
) -> list[str]:
    """Names of the parameters that positions at poses ``q`` determine (random poses within the
    limits, tool above the floor, when ``q`` is None), in the model's order.

    The lab's analysis (:func:`lab.identifiability.analyse_model`: column-scaled Jacobian, rank by
    orthogonalisation in a calibration engineer's priority order, and, given the per-axis ``noise``
    (m), parameters the data determine no better than their typical size left out as weak) when
    the lab is installed; otherwise :func:`qr_identifiable`, a QR with column pivoting.
    """
    if q is None:
        rng = np.random.default_rng(seed)
        q = sample_poses(model.robot, n_poses, rng)
        columns = random_columns(model, len(q), rng)
    inputs = model.inputs(q, columns)
    try:
        from lab.identifiability import analyse_model
    except ImportError:
        return qr_identifiable(model, inputs, p)
    ident = analyse_model(model, inputs, p, noise=noise, warn=False)
    return list(ident.identifiable_names)


def merge_effects(model: ErrorModel, effects: str | Sequence[str | Effect]) -> list[str]:
    """The effect labels of ``model`` with ``effects`` added: a per-joint effect that the model
    has already takes the union of the joints (``backlash[1]`` + ``backlash[5]`` =
    ``backlash[1,5]``; on all joints it stays on all; a cyclic effect takes the union of the
    orders of each joint), a new one is appended. A diagnosis's
    suggestion (``geometric,backlash[1,5]``), which repeats the model's effects, merges to
    itself."""
    return [e.label for e in union_of([*model.effects, *parse_effects(effects)])]


class MeasurementBuffer:
    """The last ``capacity`` tracker points with the inputs the model's effects need, as the lab's
    measurement files have them (docs/format.md, the measurement CSV): the encoder reading ``q``
    when the point was sampled, the point ``x, y, z``, and the columns ``t`` (s),
    ``temperature`` (the sensor's, degC), ``payload`` (the declared load, kg) and ``dir1..dir6``
    (the commanded direction of each joint, +-1); the gravity torques follow from q and the payload
    (:meth:`gravity_torques`, the nominal arm's, as the lab computes them). Each point also
    says whether the estimator accepted it.

    Points are numbered from the first ever appended (:attr:`total`), so a window survives the
    oldest points being dropped: ``buffer.to_measurements(since=k)``.
    """

    COLUMNS = ("t", "temperature", "payload", *(f"dir{i}" for i in range(1, 7)))

    def __init__(self, capacity: int = 1000) -> None:
        refuse_settings(BUFFER_SETTINGS, capacity=capacity)
        self.capacity = int(capacity)
        self._q = np.empty((capacity, 6))
        self._xyz = np.empty((capacity, 3))
        self._cols = np.full((capacity, len(self.COLUMNS)), np.nan)
        self._accepted = np.zeros(capacity, dtype=bool)
        self.total = 0  # points ever appended

    def __len__(self) -> int:
        return min(self.total, self.capacity)

    @property
    def first(self) -> int:
        """The number of the oldest point still held."""
        return self.total - len(self)

    def append(
        self, q: np.ndarray, xyz: np.ndarray, columns: Mapping[str, float], accepted: bool = True
    ) -> None:
        k = self.total % self.capacity
        self._q[k] = q
        self._xyz[k] = xyz
        row = self._cols[k]
        for j, name in enumerate(self.COLUMNS):
            v = columns.get(name)
            row[j] = math.nan if v is None else v
        self._accepted[k] = accepted
        self.total += 1

    def _rows(self, since: int, until: int | None) -> np.ndarray:
        lo = max(int(since), self.first)
        hi = self.total if until is None else min(int(until), self.total)
        return np.arange(lo, max(hi, lo)) % self.capacity

    def count(self, since: int = 0, until: int | None = None, accepted_only: bool = True) -> int:
        rows = self._rows(since, until)
        return int(self._accepted[rows].sum()) if accepted_only else len(rows)

    def to_measurements(
        self,
        since: int = 0,
        until: int | None = None,
        accepted_only: bool = True,
        source: str = "tracker buffer",
    ) -> MeasurementSet:
        """Points ``since`` .. ``until`` (numbers as :attr:`total` counts them) as a
        :class:`~arm.measurements.MeasurementSet`; a column with a missing value among them is
        left out (the effects that need it cannot be tested on these points)."""
        rows = self._rows(since, until)
        if accepted_only:
            rows = rows[self._accepted[rows]]
        cols = {}
        for j, name in enumerate(self.COLUMNS):
            v = self._cols[rows, j]
            if v.size and np.all(np.isfinite(v)):
                cols[name] = v.copy()
        return MeasurementSet(self._q[rows].copy(), self._xyz[rows].copy(), cols, source)

    def gravity_torques(self, robot, since: int = 0, until: int | None = None) -> np.ndarray:
        """(N, 6) gravity torques of the nominal arm at the points' q with the declared payload
        (N*m), as :meth:`arm.errormodel.ErrorModel.inputs` computes them for the lab."""
        data = self.to_measurements(since, until, accepted_only=False)
        payload = data.columns.get("payload")
        return gravity_torques(robot.to_modified(), data.q, payload=payload)


_FREE_CACHE: dict[tuple, list[str]] = {}


def cached_identifiable(model: ErrorModel) -> list[str]:
    """:func:`identifiable_parameters` of ``model`` on its default random poses, computed once
    per process for each (description, effects, targets)."""
    key = (model.robot.to_toml(), tuple(model.effect_names), model.targets)
    if key not in _FREE_CACHE:
        _FREE_CACHE[key] = identifiable_parameters(model)
    return list(_FREE_CACHE[key])


def qr_identifiable(
    model: ErrorModel, inputs, p: np.ndarray | None = None, tol: float = 1e-8
) -> list[str]:
    """Identifiable parameters by QR with column pivoting of the identification Jacobian at these
    inputs, each column scaled to unit norm: a parameter is kept when its pivot exceeds ``tol``
    times the largest, i.e. it is not (nearly) a combination of those kept before it; of a
    dependent group the pivoting keeps one member, the others stay at nominal. Columns that move
    nothing (below 1e-12 of the largest) are left out first."""
    _, J = model.predict(inputs, model.nominal() if p is None else p, jacobian=True)
    J = J.reshape(-1, J.shape[-1])
    norms = np.linalg.norm(J, axis=0) * prior_scales(model)
    live = norms > 1e-12 * max(norms.max(), 1e-300)
    Js = J[:, live] / np.linalg.norm(J[:, live], axis=0)
    _, R, piv = scipy.linalg.qr(Js, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > tol * d[0])) if d.size else 0
    keep = sorted(np.flatnonzero(live)[piv[:rank]])
    return [model.layout.names[k] for k in keep]


class _CompiledUpdate:
    """One measurement's update of :class:`RecursiveLeastSquares` as one compiled CasADi
    function, called through its own buffers (:class:`~agents.tool_model.BufferedFunction`).

    In: the tool model's packed input at the measurement, the measured point ``y``, the scaled
    estimate ``z`` and the information matrix. Out: the innovation ``e``, and the estimate (scaled
    and in SI units) and the information after accepting the point (the caller keeps them or not,
    by its gate). The tool point and its derivative by the free parameters, the information
    update and the gradient are scalar expressions (SX); the step ``info^-1 grad`` is solved by
    CasADi's own sparse LDL' (no dependency, 5 us for 25 parameters).

    The information is refactored at every update, not updated: the regularised forgetting adds
    ``(1 - lam) I``, a full-rank term that a rank-one (or rank-3) Cholesky update cannot take;
    the factorisation's flops cost microseconds. What the numpy version spent (0.3 ms) was the
    dispatch of some thirty small calls; this is one call.

    ``predictive=True`` also gives the point's predictive density under the estimate before it:
    two more outputs, the normalised innovation ``e' S^-1 e`` and ``log det S``, with ``S = H
    A^-1 H' + sigma^2 I`` the innovation's covariance (``A = lam info + (1 - lam) I``, the
    information before the point). They come from the same factorisation, by the matrix
    inversion lemma: ``S^-1 = (I - H info1^-1 H' / sigma^2) / sigma^2``.
    """

    def __init__(
        self,
        tm: ToolModel,
        idx: np.ndarray,
        scale: np.ndarray,
        p0_free: np.ndarray,
        sigma: float,
        lam: float,
        predictive: bool = False,
    ) -> None:
        n = len(idx)
        P, nc = len(tm.layout), len(tm.column_names)
        zq = ca.SX.sym("zq", tm.n_inputs)
        y, z = ca.SX.sym("y", 3), ca.SX.sym("z", n)
        info = ca.SX.sym("info", n, n)
        p = zq[6 : 6 + P]
        x = tm.expression(zq[:6], p, zq[6 + P : 6 + P + nc], zq[6 + P + nc :])
        ps = ca.vertcat(*(p[int(k)] for k in idx))
        H = ca.jacobian(x, ps) @ ca.diag(ca.DM(scale))  # (3, n): scaled parameters
        e = y - x
        r_inv = 1.0 / sigma**2
        # lam info + (1 - lam) I + r_inv H'H, each entry below the diagonal built once and used
        # twice: a symmetric matrix at half the operations
        rows: list[list] = [[None] * n for _ in range(n)]
        for i in range(n):
            for j in range(i + 1):
                v = lam * info[i, j] + r_inv * (
                    H[0, i] * H[0, j] + H[1, i] * H[1, j] + H[2, i] * H[2, j]
                )
                rows[i][j] = rows[j][i] = v + (1.0 - lam) if i == j else v
        info1 = ca.vertcat(*(ca.horzcat(*r) for r in rows))
        grad = r_inv * ca.mtimes(H.T, e) - (1.0 - lam) * z
        outs = [e, ca.densify(info1), ca.densify(grad)]
        if predictive:
            outs.append(ca.densify(H))
        core = ca.Function("rls_core", [zq, y, z, info], outs)
        nz = tm.n_inputs
        w = ca.MX.sym("w", nz + 3 + n + n * n)
        z_mx = w[nz + 3 : nz + 3 + n]
        e_, info_, grad_, *H_ = core(
            w[:nz], w[nz : nz + 3], z_mx, ca.reshape(w[nz + 3 + n :], n, n)
        )
        if predictive:
            # one factorisation, four right-hand sides: the step and info1^-1 H'
            sol = ca.solve(info_, ca.horzcat(grad_, H_[0].T), "ldl")
            dz, X = sol[:, 0], sol[:, 1:]
            s_inv = (ca.DM.eye(3) - ca.mtimes(H_[0], X) * r_inv) * r_inv
            s_inv = 0.5 * (s_inv + s_inv.T)
            extra = [ca.bilin(s_inv, e_, e_), -ca.log(ca.det(s_inv))]
        else:
            dz, extra = ca.solve(info_, grad_, "ldl"), []
        z1 = z_mx + dz
        out = ca.vertcat(e_, z1, ca.DM(p0_free) + ca.DM(scale) * z1, ca.vec(info_), *extra)
        self.function = ca.Function("rls_update", [w], [out])
        self.n = n


_UPDATE_CACHE: dict[tuple, _CompiledUpdate] = {}


def compiled_update(
    tm: ToolModel,
    idx: np.ndarray,
    scale: np.ndarray,
    p0_free: np.ndarray,
    sigma: float,
    lam: float,
    predictive: bool = False,
) -> BufferedFunction:
    """A buffered :class:`_CompiledUpdate`, its function built once per process for each (tool
    model, free set, prior, noise, forgetting, predictive or not)."""
    key = (
        id(tm._f_p),
        tuple(int(k) for k in idx),
        tuple(map(float, scale)),
        tuple(map(float, p0_free)),
        float(sigma),
        float(lam),
        bool(predictive),
    )
    cu = _UPDATE_CACHE.get(key)
    if cu is None:
        if len(_UPDATE_CACHE) > 256:
            _UPDATE_CACHE.clear()
        cu = _CompiledUpdate(tm, idx, scale, p0_free, sigma, lam, predictive)
        _UPDATE_CACHE[key] = cu
    return BufferedFunction(cu.function)


class RecursiveLeastSquares:
    """Online estimate of an error model's parameters from single tracker measurements.

    ``free``: names to estimate (default: :func:`identifiable_parameters` of the model);
    ``sigma``: the instrument's per-axis noise (m); ``forgetting``: lam per accepted measurement
    (1 = none; 0.99 remembers about 100 measurements); ``p0``: starting values (default nominal);
    ``scales``: prior standard deviations (default :func:`prior_scales`, times ``prior_factor``).

    :meth:`widen` adds effects during an episode, keeping what was learned.
    """

    def __init__(
        self,
        model: ErrorModel,
        free: Sequence[str] | None = None,
        sigma: float = 15e-6,
        forgetting: float = 0.995,
        p0: np.ndarray | None = None,
        scales: np.ndarray | None = None,
        prior_factor: float = 2.0,
        gate: float = CHI2_3_GATE,
        robust_factor: float = 6.0,
        max_rejections: int = 5,
        tool_model: ToolModel | None = None,
    ) -> None:
        refuse_settings(ESTIMATOR_SETTINGS, sigma=sigma, forgetting=forgetting)
        self.sigma = float(sigma)
        self.forgetting = float(forgetting)
        self.gate = float(gate)
        self.robust_factor = float(robust_factor)
        self.max_rejections = int(max_rejections)
        self.prior_factor = float(prior_factor)
        self._set_model(model, free, p0, scales, tool_model)
        self.reset()

    def _set_model(self, model, free, p0, scales, tool_model) -> None:
        self.model = model
        self.layout = model.layout
        self.free = list(identifiable_parameters(model) if free is None else free)
        self.idx = self.layout.indices(self.free)
        self.p0 = model.nominal() if p0 is None else np.array(p0, dtype=float)
        if self.p0.shape != (len(self.layout),):
            raise AgentError(f"p0 must have {len(self.layout)} values, got {self.p0.shape}")
        s = prior_scales(model) if scales is None else np.asarray(scales, dtype=float)
        self.scale = self.prior_factor * s[self.idx]
        self._p0_free = self.p0[self.idx]
        if tool_model is None:
            from agents.tool_model import ToolModel, UnsupportedEffectError

            try:
                tool_model = ToolModel(model)
            except UnsupportedEffectError:
                tool_model = None
        self._tm = tool_model
        self._compiled: BufferedFunction | None = None
        self._fast = False
        if tool_model is not None:
            self._compiled = compiled_update(
                tool_model, self.idx, self.scale, self._p0_free, self.sigma, self.forgetting
            )
            self._bind(tool_model, self._compiled)

    def _bind(self, tm: ToolModel, cf: BufferedFunction) -> None:
        """Views of the compiled update's argument ``[q, p, columns, offsets, y, z, info]``: an
        update writes the point and the state into it in place, without packing or
        concatenating (the Python around the compiled call is most of an update's cost)."""
        n, P, nc, nz = len(self.idx), len(tm.layout), len(tm.column_names), tm.n_inputs
        a = cf.arg
        self._a_q, self._a_p, self._a_c = a[:6], a[6 : 6 + P], a[6 + P : 6 + P + nc]
        self._a_y, self._a_z, self._a_info = a[nz : nz + 3], a[nz + 3 : nz + 3 + n], a[nz + 3 + n :]
        self._col_defaults = [
            (k, c, tm.column_vector({})[k]) for k, c in enumerate(tm.column_names)
        ]
        self._fast = not tm._custom  # a user's effect needs its numpy offsets: pack()

    def reset(self) -> None:
        n = len(self.idx)
        self._z = np.zeros(n)
        self._info = np.eye(n)  # the information of the scaled parameters
        self._p = self.p0.copy()
        self.n_updates = 0
        self.n_rejected = 0
        self._run_rejected = 0
        self._recent: deque[float] = deque(maxlen=25)
        self.last_innovation = np.full(3, np.nan)
        self.widenings: list[dict] = []

    # -- state ---------------------------------------------------------------------------------
    @property
    def params(self) -> np.ndarray:
        """The full parameter vector: estimates for the free ones, ``p0`` for the rest."""
        return self._p.copy()

    @property
    def z(self) -> np.ndarray:
        """The estimate of the free parameters, scaled: ``(p - p0) / scale``."""
        return self._z.copy()

    @property
    def info(self) -> np.ndarray:
        """The information matrix of the scaled free parameters ``(p - p0) / scale`` (a copy)."""
        return self._info.copy()

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of the free parameters (SI units), from the information matrix."""
        cov = np.linalg.inv(self.info)
        return self.scale * np.sqrt(np.clip(np.diag(cov), 0.0, None))

    def estimate(self) -> dict[str, float]:
        """The free parameters by name."""
        return dict(zip(self.free, map(float, self.params[self.idx]), strict=True))

    # -- widening ------------------------------------------------------------------------------
    def _check_wider(self, model: ErrorModel) -> None:
        missing = [nm for nm in self.layout.names if nm not in model.layout.names]
        if missing:
            raise AgentError(
                f"widen: the new model ({', '.join(model.effect_names)}) lacks parameter(s) "
                f"{', '.join(missing[:5])}; it must have every parameter of the current one "
                f"({', '.join(self.model.effect_names)})"
            )

    def widened_free(self, model: ErrorModel) -> list[str]:
        """The free parameters after widening to ``model``: the current ones, then those of the
        new parameters that the model's identifiability analysis keeps (it offers the geometric
        parameters first), in the model's order."""
        self._check_wider(model)
        keep, old = set(self.free), set(self.layout.names)
        new = {nm for nm in cached_identifiable(model) if nm not in old}
        return [nm for nm in model.layout.names if nm in keep or nm in new]

    def prepare_widening(
        self, model: ErrorModel, free: Sequence[str], tool_model: ToolModel | None
    ) -> None:
        """Build (and cache) the compiled update that :meth:`widen` to ``model`` will use, without
        changing this estimator: the slow part of widening, for a thread off the control path."""
        if tool_model is None:
            return
        idx = model.layout.indices(list(free))
        scales = prior_scales(model)
        scales[model.layout.indices(self.free)] = self.scale / self.prior_factor
        p0 = model.nominal()
        p0[model.layout.indices(list(self.layout.names))] = self.p0
        compiled_update(
            tool_model, idx, self.prior_factor * scales[idx], p0[idx], self.sigma, self.forgetting
        )

    def widen(
        self,
        model: ErrorModel,
        free: Sequence[str] | None = None,
        tool_model: ToolModel | None = None,
    ) -> list[str]:
        """Continue with ``model``, which has every parameter of the current one and more (effects
        added, e.g. by a diagnosis), keeping what was learned: the estimates and the information
        of the parameters already estimated (cross-information included) stay as they are; the
        new free parameters start from ``model``'s nominal values with their prior information,
        uncorrelated with the rest. ``free``: the names to estimate (default: the current ones,
        then those of the new parameters that the model's identifiability analysis keeps, which
        offers the geometric parameters first). Returns the names added.
        """
        old_names = list(self.layout.names)
        self._check_wider(model)
        free = self.widened_free(model) if free is None else list(free)
        lost = [nm for nm in self.free if nm not in free]
        if lost:
            raise AgentError(f"widen: free parameter(s) {', '.join(lost)} would be dropped")
        added = [nm for nm in free if nm not in self.free]
        p_full = model.nominal()
        p_full[model.layout.indices(old_names)] = self._p
        p0 = model.nominal()
        p0[model.layout.indices(old_names)] = self.p0
        z, info = self.z, self.info
        old_free = list(self.free)
        scales = prior_scales(model)  # the prior of the parameters kept is kept too
        scales[model.layout.indices(old_free)] = self.scale / self.prior_factor
        self._set_model(model, free, p0, scales, tool_model)
        n = len(self.free)
        pos = np.array([self.free.index(nm) for nm in old_free], dtype=int)
        self._z = np.zeros(n)
        self._z[pos] = z
        self._info = np.eye(n)
        self._info[np.ix_(pos, pos)] = info
        # the estimate stays where it was; new free parameters from their nominal (prior) value
        self._p = p_full
        self._p[self.idx] = self.p0[self.idx] + self.scale * self._z
        self.widenings.append({"updates": self.n_updates, "added": added})
        log.info("estimator widened to %s: +%s", ", ".join(model.effect_names), ", ".join(added))
        return added

    # -- measurements --------------------------------------------------------------------------
    def _predict(self, q: np.ndarray, columns: Mapping[str, float], p: np.ndarray):
        if self._tm is not None:
            x, Jp = self._tm.point_dp(q, p, columns)
            return x, Jp
        need = self.model.required_columns() | {"payload"}
        cols = {}
        for c in need:
            v = columns.get(c)
            if v is None or not np.isfinite(v):
                v = self.model.robot.payload if c == "payload" else 0.0
            cols[c] = np.array([float(v)])
        x, J = self.model.predict(self.model.inputs(q[None, :], cols), p, jacobian=True)
        return x[0], J[0]

    def innovation(self, q: np.ndarray, columns: Mapping[str, float], y: np.ndarray) -> np.ndarray:
        """``y - f(q, p)`` at the current estimate (m)."""
        x, _ = self._predict(np.asarray(q, dtype=float), columns, self.params)
        return np.asarray(y, dtype=float) - x

    def update(
        self,
        q: np.ndarray,
        y: np.ndarray,
        columns: Mapping[str, float] | None = None,
    ) -> bool:
        """Fold in one measurement ``y`` (3,) of the tool point at encoder reading ``q`` (6,);
        returns whether it was accepted. Non-finite input is ignored (returns False).

        With a CasADi form of the model the whole update is one compiled call
        (:class:`_CompiledUpdate`); without one (a user's chain effect), numpy and LAPACK."""
        if not (isinstance(q, np.ndarray) and q.shape == (6,) and q.dtype == float):
            q = np.asarray(q, dtype=float).reshape(6)
        if not (isinstance(y, np.ndarray) and y.shape == (3,) and y.dtype == float):
            y = np.asarray(y, dtype=float).reshape(3)
        columns = columns or {}
        n = len(self.idx)
        cf = self._compiled
        if cf is not None and self._fast:
            self._a_q[:] = q
            self._a_p[:] = self._p
            a_c = self._a_c
            for k, name, default in self._col_defaults:
                v = columns.get(name)
                a_c[k] = v if v is not None and math.isfinite(v) else default
            self._a_y[:] = y
            self._a_z[:] = self._z
            self._a_info[:] = self._info.reshape(-1)
            out = cf.evaluate()
            e = out[:3].copy()
        elif not math.isfinite(q @ q + y @ y):  # one scalar test: NaN and inf propagate
            return False
        elif cf is not None and self._tm is not None:
            zq = self._tm.pack(q, self._p, columns)
            out = cf(np.concatenate([zq, y, self._z, self._info.reshape(-1)]))
            e = out[:3].copy()
        else:
            out = None
            x, Jp = self._predict(q, columns, self._p)
            e = y - x
        e0, e1, e2 = e.tolist()
        enorm = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        if not math.isfinite(enorm):  # a NaN or inf in q or y: the innovation says so
            return False
        self.last_innovation = e
        # the gate rejects a point far above the recent typical innovation *and* beyond the
        # chi-square gate; the normalised innovation is computed only for the first kind (and
        # the recent median only for a point above the least it can be)
        floor = math.sqrt(3.0) * self.sigma
        if enorm > self.robust_factor * floor and self._run_rejected < self.max_rejections:
            recent = sorted(self._recent)
            typical = max(recent[len(recent) // 2] if recent else 0.0, floor)
            if enorm > self.robust_factor * typical and (
                self.normalised_innovation(q, columns, e) > self.gate
            ):
                self.n_rejected += 1
                self._run_rejected += 1
                log.debug("measurement rejected: innovation %.3g mm", enorm * 1e3)
                return False
        self._run_rejected = 0
        self._recent.append(enorm)
        if out is not None:
            self._z = out[3 : 3 + n].copy()
            p = self.p0.copy()
            p[self.idx] = out[3 + n : 3 + 2 * n]
            self._info = out[3 + 2 * n : 3 + 2 * n + n * n].reshape(n, n).copy()
        else:
            lam, r_inv = self.forgetting, 1.0 / self.sigma**2
            H = Jp[:, self.idx] * self.scale
            info = lam * self._info + (1.0 - lam) * np.eye(n) + r_inv * (H.T @ H)
            grad = r_inv * (H.T @ e) - (1.0 - lam) * self._z
            _, dz, bad = lapack.dposv(info, grad, lower=1)
            if bad:
                raise np.linalg.LinAlgError(f"estimator information not positive definite ({bad})")
            self._info, self._z = info, self._z + dz
            p = self.p0.copy()
            p[self.idx] = self._p0_free + self.scale * self._z
        self._p = p
        self.n_updates += 1
        return True

    def normalised_innovation(
        self, q: np.ndarray, columns: Mapping[str, float], e: np.ndarray | None = None
    ) -> float:
        """``e' S^-1 e`` of the innovation ``e`` at pose ``q`` (default ``y - f(q, p)`` is not
        known here: pass ``e``), with ``S = H info^-1 H' + sigma^2 I`` its covariance under the
        current estimate: chi-square with 3 degrees of freedom when the model is right."""
        _, Jp = self._predict(np.asarray(q, dtype=float).reshape(6), columns, self._p)
        H = Jp[:, self.idx] * self.scale
        X = scipy.linalg.cho_solve((np.linalg.cholesky(self._info), True), H.T)
        S = H @ X + self.sigma**2 * _I3
        e = np.asarray(e, dtype=float).reshape(3)
        try:
            return float(e @ np.linalg.solve(S, e))
        except np.linalg.LinAlgError:
            return math.inf

    def report(self) -> dict[str, float | list]:
        return {
            "rls_updates": self.n_updates,
            "rls_rejected": self.n_rejected,
            "rls_free": list(self.free),
            "rls_estimate": [float(v) for v in self.params[self.idx]],
        }
