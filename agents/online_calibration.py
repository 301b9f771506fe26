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
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Mapping, Sequence

import numpy as np
import scipy.linalg

from arm.errormodel import ErrorModel
from arm.sampling import sample_poses

__all__ = [
    "RecursiveLeastSquares",
    "identifiable_parameters",
    "prior_scales",
    "qr_identifiable",
    "random_columns",
]

log = logging.getLogger(__name__)

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


class RecursiveLeastSquares:
    """Online estimate of an error model's parameters from single tracker measurements.

    ``free``: names to estimate (default: :func:`identifiable_parameters` of the model);
    ``sigma``: the instrument's per-axis noise (m); ``forgetting``: lam per accepted measurement
    (1 = none; 0.99 remembers about 100 measurements); ``p0``: starting values (default nominal);
    ``scales``: prior standard deviations (default :func:`prior_scales`, times ``prior_factor``).
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
        tool_model=None,
    ) -> None:
        if not 0.0 < forgetting <= 1.0:
            raise ValueError(f"forgetting must be in (0, 1], got {forgetting}")
        if sigma <= 0:
            raise ValueError(f"sigma must be positive, got {sigma}")
        self.model = model
        self.layout = model.layout
        self.free = list(identifiable_parameters(model) if free is None else free)
        self.idx = self.layout.indices(self.free)
        self.p0 = model.nominal() if p0 is None else np.array(p0, dtype=float)
        if self.p0.shape != (len(self.layout),):
            raise ValueError(f"p0 must have {len(self.layout)} values, got {self.p0.shape}")
        s = prior_scales(model) if scales is None else np.asarray(scales, dtype=float)
        self.scale = prior_factor * s[self.idx]
        self.sigma = float(sigma)
        self.forgetting = float(forgetting)
        self.gate = float(gate)
        self.robust_factor = float(robust_factor)
        self.max_rejections = int(max_rejections)
        if tool_model is None:
            from agents.tool_model import ToolModel, UnsupportedEffectError

            try:
                tool_model = ToolModel(model)
            except UnsupportedEffectError:
                tool_model = None
        self._tm = tool_model
        self.reset()

    def reset(self) -> None:
        n = len(self.idx)
        self.z = np.zeros(n)
        self.info = np.eye(n)
        self._chol = np.eye(n)  # lower Cholesky factor of ``info``
        self._p = self.p0.copy()
        self.n_updates = 0
        self.n_rejected = 0
        self._run_rejected = 0
        self._recent = deque(maxlen=25)
        self.last_innovation = np.full(3, np.nan)

    # -- state ---------------------------------------------------------------------------------
    @property
    def params(self) -> np.ndarray:
        """The full parameter vector: estimates for the free ones, ``p0`` for the rest."""
        return self._p.copy()

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of the free parameters (SI units), from the information matrix."""
        cov = np.linalg.inv(self.info)
        return self.scale * np.sqrt(np.clip(np.diag(cov), 0.0, None))

    def estimate(self) -> dict[str, float]:
        """The free parameters by name."""
        return dict(zip(self.free, map(float, self.params[self.idx]), strict=True))

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
        self, q: np.ndarray, y: np.ndarray, columns: Mapping[str, float] | None = None
    ) -> bool:
        """Fold in one measurement ``y`` (3,) of the tool point at encoder reading ``q`` (6,);
        returns whether it was accepted. Non-finite input is ignored (returns False)."""
        q = np.asarray(q, dtype=float).reshape(6)
        y = np.asarray(y, dtype=float).reshape(3)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(y))):
            return False
        columns = columns or {}
        x, Jp = self._predict(q, columns, self._p)
        e = y - x
        H = Jp[:, self.idx] * self.scale  # (3, n) in scaled parameters
        r_inv = 1.0 / self.sigma**2
        # innovation covariance H info^-1 H' + R, with the Cholesky factor of the last update
        # (cho_solve, not solve_triangular: OpenBLAS's threaded trsm took 9 ms here for 25x3)
        S = H @ scipy.linalg.cho_solve((self._chol, True), H.T, check_finite=False)
        S[np.diag_indices(3)] += self.sigma**2
        d2 = float(e @ np.linalg.solve(S, e))
        enorm = float(np.sqrt(e @ e))
        recent = sorted(self._recent)
        typical = max(recent[len(recent) // 2] if recent else 0.0, np.sqrt(3) * self.sigma)
        self.last_innovation = e
        if (
            d2 > self.gate
            and enorm > self.robust_factor * typical
            and self._run_rejected < self.max_rejections
        ):
            self.n_rejected += 1
            self._run_rejected += 1
            log.debug("measurement rejected: innovation %.3g mm, d2 %.3g", enorm * 1e3, d2)
            return False
        self._run_rejected = 0
        self._recent.append(enorm)
        lam = self.forgetting
        info = self.info
        info *= lam
        info[np.diag_indices_from(info)] += 1.0 - lam
        info += r_inv * (H.T @ H)
        self._chol = np.linalg.cholesky(info)
        grad = r_inv * (H.T @ e) - (1.0 - lam) * self.z
        self.z = self.z + scipy.linalg.cho_solve((self._chol, True), grad, check_finite=False)
        self._p = self.p0.copy()
        self._p[self.idx] += self.scale * self.z
        self.n_updates += 1
        return True

    def report(self) -> dict[str, float | list]:
        return {
            "rls_updates": self.n_updates,
            "rls_rejected": self.n_rejected,
            "rls_free": list(self.free),
            "rls_estimate": [float(v) for v in self.params[self.idx]],
        }
