"""Forward selection of regressors, shared by the diagnosis (catalogued effects) and discovery
(library terms): the F-test of added columns, Holm's step-down, and the leave-one-pose-out error
of a linear least-squares fit from its hat matrix (PRESS), updated column block by column block.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import stats

from lab.errors import FitError
from lab.identifiability import orthonormal_basis

__all__ = ["ForwardSelection", "f_test", "holm", "press_rms"]

DEPENDENT = 1e-6  # a candidate column this much outside the model's span is dependent on it


def hat_blocks(Q: np.ndarray, per_pose: int = 3) -> np.ndarray:
    """The (N, k, k) diagonal blocks of the hat matrix of orthonormal regressors ``Q`` (kN, m),
    k rows per pose (3: a point; 6: a point and an orientation)."""
    Qb = Q.reshape(Q.shape[0] // per_pose, per_pose, -1)
    return np.matmul(Qb, Qb.transpose(0, 2, 1))


def press_rms(e: np.ndarray, H: np.ndarray) -> float:
    """Leave-one-pose-out RMS (3-D: of a pose's k rows) of a linear least-squares fit whose
    residual is ``e`` (kN) and whose hat matrix has the diagonal blocks ``H`` (N, k, k):
    e_(-i) = (I - H_ii)^-1 e_i."""
    n, k = H.shape[0], H.shape[1]
    loo = np.linalg.solve(np.eye(k) - H, e.reshape(n, k, 1))[:, :, 0]
    return float(np.sqrt(np.mean(np.sum(loo**2, axis=1))))


def holm(p: np.ndarray, alpha: float) -> np.ndarray:
    """Holm's step-down: which hypotheses are rejected at family-wise level ``alpha``."""
    m = len(p)
    sig = np.zeros(m, dtype=bool)
    for i, k in enumerate(np.argsort(p, kind="stable")):
        if p[k] > alpha / (m - i):
            break
        sig[k] = True
    return sig


def f_test(ss: float, k: int, rss: float, dof: int) -> tuple[float, float]:
    """(F, p-value) of ``k`` added columns that explain ``ss`` of the residual sum of squares,
    leaving ``rss`` with ``dof`` degrees of freedom."""
    if k <= 0 or dof <= 0 or rss <= 0:
        return 0.0, 1.0
    F = (ss / k) / (rss / dof)
    return float(F), float(stats.f.sf(F, k, dof))


class ForwardSelection:
    """Forward selection state: the residual, its sum of squares and degrees of freedom, the hat
    blocks and the held-out RMS after the chosen columns (``Q``, orthonormal).

    A candidate's columns are given as an orthonormal, model-free array, or as a function that
    builds one: then no copy of them outlives the trial (200,000 poses of a dozen columns are
    20 MB a candidate), and the trials before anything is chosen are remembered by key as
    their outcome only."""

    def __init__(self, e, rss, dof, H, cv):
        self.e, self.rss, self.dof, self.H, self.cv = e, rss, dof, H, cv
        self.Q = np.empty((e.size, 0))
        self._first: dict[int, tuple | None] = {}  # trials before anything is chosen, by key

    def trial(self, basis: np.ndarray | Callable[[], np.ndarray], key: int | None = None):
        """(held-out RMS, p-value, state pieces) of adding ``basis``; None if it adds nothing.
        Trials on the initial state are remembered by ``key`` (without the pieces when the
        basis is built by a function: :meth:`add` builds them again)."""
        if self.Q.shape[1] > 0 or key is None:
            return self._trial(basis)
        if key in self._first:
            return self._first[key]
        out = self._trial(basis)
        self._first[key] = (out[0], out[1], None) if out and callable(basis) else out
        return out

    def _trial(self, basis):
        fresh = callable(basis)
        X = basis() if fresh else basis
        if self.Q.shape[1]:  # in place when the basis is this trial's own
            proj_Q = self.Q @ (self.Q.T @ X)
            X = np.subtract(X, proj_Q, out=X if fresh else None)
        X = X[:, np.linalg.norm(X, axis=0) > DEPENDENT]  # the columns had norm 1
        Qc = orthonormal_basis(X, overwrite=True)  # X is a copy: fancy indexing
        k = Qc.shape[1]
        if k == 0 or self.dof - k <= 0:
            return None
        proj = Qc.T @ self.e
        ss = float(proj @ proj)
        _, pv = f_test(ss, k, self.rss - ss, self.dof - k)
        H = self.H + hat_blocks(Qc, self.H.shape[1])
        return press_rms(self.e - Qc @ proj, H), pv, (Qc, proj, ss, H)

    def add(self, cv, pieces, basis: np.ndarray | Callable[[], np.ndarray] | None = None) -> None:
        """Add a trial's columns: its ``pieces``, or those that ``basis`` builds again."""
        if pieces is None:
            if basis is None:
                raise FitError("a remembered trial has no pieces: give its basis")
            out = self._trial(basis)
            if out is None:
                return
            cv, _, pieces = out
        Qc, proj, ss, H = pieces
        self.e = self.e - Qc @ proj
        self.rss, self.dof, self.H, self.cv = self.rss - ss, self.dof - Qc.shape[1], H, cv
        self.Q = np.hstack([self.Q, Qc])
