"""The least-squares solver of identification: Levenberg-Marquardt on scaled columns, block by block.

    prob = ScaledProblem(blocks, xyz, p0, free, scale)
    sol = solve(blocks, xyz, p0, free, scale)           # a Solution: params, residuals, Gram

The problem is stated on the free parameters ``u`` (``p = p0 + u * scale`` on them), so that every
Jacobian column has an RMS of 1 m per pose. :func:`levenberg_marquardt` takes Gauss-Newton steps
and damps them (Nielsen's update) only when one fails: once the base is registered, calibration
problems are nearly linear, and it converges in 3-5 model evaluations where MINPACK's ``lmder``
(``solver="minpack"``, through :func:`scipy.optimize.least_squares`), which always starts damped,
needs 4-10; both reach the same solution (``benchmarks/lab.py``, ``tests/test_lab_fit.py``).
A robust loss (``huber``, ``soft_l1``) runs scipy's trust-region reflective method.

The model is evaluated block by block (:mod:`lab.blocks`): each step needs only the small Gram
matrix ``A^T A`` and gradient ``A^T r``, so a whole Jacobian of 200,000 poses is never held.
A block's residual rows and Jacobian rows are formed in one place (:meth:`ScaledProblem.rows`):
one row per measured coordinate, predicted minus measured.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import least_squares
from scipy.stats import chi2

from lab.blocks import Blocks

__all__ = ["Solution", "levenberg_marquardt", "robust_sigma", "solve"]

log = logging.getLogger(__name__)

HUBER_K = 1.345  # Huber's tuning constant: 95 % efficiency on Gaussian noise
OUTLIER_RADIUS = math.sqrt(chi2.ppf(0.999, 3))  # 4.03 sigma: the 99.9 % radius of 3-D noise
MAD_TO_SIGMA = 1.4826


def robust_sigma(r: np.ndarray) -> float:
    """1.4826 times the median absolute deviation of the coordinates of ``r``: the standard
    deviation of Gaussian noise, unmoved by a few gross errors (a robust loss's scale)."""
    r = np.asarray(r, dtype=float).reshape(-1)
    if not r.size:
        return float("nan")
    return float(MAD_TO_SIGMA * np.median(np.abs(r - np.median(r))))


class ScaledProblem:
    """The scaled least-squares problem on the free parameters, evaluated block by block
    (:class:`lab.blocks.Blocks`): an evaluation gives the residual rows and the Gram matrix and
    gradient of the scaled Jacobian of the free parameters, never the whole Jacobian.

    ``target``: the measured values, one row per pose ((N, 3) points)."""

    def __init__(
        self,
        blocks: Blocks,
        target: np.ndarray,
        p0: np.ndarray,
        free: np.ndarray,
        scale: np.ndarray,
    ) -> None:
        self.blocks, self.target = blocks, target
        self.per_pose = int(target.shape[1])
        self.p0 = p0
        self.idx = np.flatnonzero(free)
        self.s = scale[self.idx]
        self._u: np.ndarray | None = None
        self._r, self._G, self._g = np.empty(0), np.empty((0, 0)), np.empty(0)
        self.last_jacobian: np.ndarray | None = None  # the whole Jacobian, when one block

    def params(self, u: np.ndarray) -> np.ndarray:
        p = self.p0.copy()
        p[self.idx] += u * self.s
        return p

    def rows(self, sl: slice, pred: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The residual rows (predicted minus measured, flat) and the scaled Jacobian rows of the
        free parameters for the poses ``sl`` of a block."""
        r = (pred - self.target[sl]).reshape(-1)
        A = J[:, :, self.idx].reshape(-1, self.idx.size) * self.s
        return r, A

    def _span(self, sl: slice) -> slice:
        return slice(self.per_pose * sl.start, self.per_pose * sl.stop)

    def evaluate(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r, G = A^T A, g = A^T r) at ``u``, A the scaled Jacobian of the free columns."""
        if self._u is not None and np.array_equal(self._u, u):
            return self._r, self._G, self._g
        p = self.params(u)
        k = self.idx.size
        r = np.empty(self.target.size)
        G, g = np.zeros((k, k)), np.zeros(k)
        for sl, pred, J in self.blocks.jacobians(p):
            rb, A = self.rows(sl, pred, J)
            if self.blocks.single:
                G, g = A.T @ A, A.T @ rb
                self.last_jacobian = J
            else:
                G += A.T @ A
                g += A.T @ rb
            r[self._span(sl)] = rb
        self._u, self._r, self._G, self._g = u.copy(), r, G, g
        return r, G, g

    def fun(self, u: np.ndarray) -> np.ndarray:
        return self.evaluate(u)[0]

    def jac(self, u: np.ndarray) -> np.ndarray:
        """The whole scaled Jacobian (rows, k), for scipy's solvers (MINPACK, robust losses)."""
        p = self.params(u)
        out = np.empty((self.target.size, self.idx.size))
        for sl, pred, J in self.blocks.jacobians(p):
            out[self._span(sl)] = self.rows(sl, pred, J)[1]
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
class Solution:
    """Where a solve stopped: the parameters, the residuals (one row per pose), the Gram matrix
    of the scaled free columns and their scale, the whole Jacobian when the data are one block,
    and the iterations and model evaluations it took."""

    params: np.ndarray
    residuals: np.ndarray  # (N, 3)
    gram: np.ndarray  # A^T A of the scaled free columns at params
    scale: np.ndarray  # the scale of those columns
    jacobian: np.ndarray | None  # (N, 3, P) at params, when the data are one block
    iterations: int
    evaluations: int


def solve(
    blocks: Blocks,
    target: np.ndarray,
    p0: np.ndarray,
    free: np.ndarray,
    scale: np.ndarray,
    loss: str = "linear",
    f_scale: float = 1.0,
    max_evaluations: int = 100,
    solver: str = "lm",
) -> Solution:
    """Solve the scaled problem from ``p0`` on the ``free`` parameters: this module's
    Levenberg-Marquardt for the linear loss (``solver="lm"``), else scipy's ``lmder``
    (``minpack``) or, for a robust ``loss``, its trust-region reflective method."""
    prob = ScaledProblem(blocks, target, p0, free, scale)
    u0 = np.zeros(prob.idx.size)
    if loss == "linear" and solver == "lm":
        u, it, nfev = levenberg_marquardt(prob.evaluate, u0, max_evaluations)
    else:
        kw: dict[str, Any] = dict(x_scale=1.0, max_nfev=max_evaluations)
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
    J = prob.last_jacobian if blocks.single else None
    return Solution(prob.params(u), r.reshape(-1, prob.per_pose), G, scale, J, it, nfev)


def irls_weights(r: np.ndarray, loss: str, f_scale: float) -> np.ndarray:
    """IRLS weights rho'(z) of scipy's losses at residual components ``r``."""
    z = (np.asarray(r) / f_scale) ** 2
    if loss == "huber":
        return np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0)))
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1.0 + z)
    return np.ones_like(z)


def weighted_gram(
    blocks: Blocks, p: np.ndarray, free: np.ndarray, scale: np.ndarray, w: np.ndarray
) -> np.ndarray:
    """``A^T W A`` of the scaled free columns at ``p``, W the IRLS weights (one row per pose)."""
    idx = np.flatnonzero(free)
    G = np.zeros((idx.size, idx.size))
    for sl, _, J in blocks.jacobians(p):
        A = J[:, :, idx].reshape(-1, idx.size) * scale[idx]
        A = A * np.sqrt(w[sl].reshape(-1))[:, None]
        G += A.T @ A
    return G


def standard_errors(
    G: np.ndarray,
    r: np.ndarray,
    free: np.ndarray,
    scale: np.ndarray,
    w: np.ndarray | None = None,
    n_rows: int | None = None,
) -> tuple[np.ndarray, float]:
    """Standard errors from the Gram matrix ``G`` of the scaled free columns (weighted for a
    robust fit): ``cov = s^2 G^-1``, ``s^2 = sum w r^2 / (rows - rank)``, ``n_rows`` the rows
    measured (default every row of ``r``). Returns the standard errors (NaN where not free) and
    ``s``."""
    idx = np.flatnonzero(free)
    rr = r.reshape(-1)
    if w is not None:
        rr = rr * np.sqrt(w.reshape(-1))
    dof = max((rr.size if n_rows is None else n_rows) - idx.size, 1)
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
