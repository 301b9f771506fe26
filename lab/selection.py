"""Forward selection of regressors, shared by the diagnosis (catalogued effects) and discovery
(library terms): the F-test of added columns, Holm's step-down, and the leave-one-pose-out error
of a linear least-squares fit from its hat matrix (PRESS), updated column block by column block.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from lab.identifiability import orthonormal_basis

__all__ = ["DEPENDENT", "ForwardSelection", "f_test", "hat_blocks", "holm", "press_rms"]

DEPENDENT = 1e-6  # a candidate column this much outside the model's span is dependent on it


def hat_blocks(Q: np.ndarray) -> np.ndarray:
    """The (N, 3, 3) diagonal blocks of the hat matrix of orthonormal regressors ``Q`` (3N, m)."""
    Qb = Q.reshape(Q.shape[0] // 3, 3, -1)
    return np.matmul(Qb, Qb.transpose(0, 2, 1))


def press_rms(e: np.ndarray, H: np.ndarray) -> float:
    """Leave-one-pose-out RMS (3-D) of a linear least-squares fit whose residual is ``e`` (3N)
    and whose hat matrix has the diagonal blocks ``H`` (N, 3, 3): e_(-i) = (I - H_ii)^-1 e_i."""
    n = H.shape[0]
    loo = np.linalg.solve(np.eye(3) - H, e.reshape(n, 3, 1))[:, :, 0]
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
    blocks and the held-out RMS after the chosen columns (``Q``, orthonormal)."""

    def __init__(self, e, rss, dof, H, cv):
        self.e, self.rss, self.dof, self.H, self.cv = e, rss, dof, H, cv
        self.Q = np.empty((e.size, 0))
        self._first: dict[int, tuple | None] = {}  # trials before anything is chosen, by key

    def trial(self, basis: np.ndarray, key: int | None = None):
        """(held-out RMS, p-value, state pieces) of adding ``basis`` (orthonormal, model-free);
        None if it adds nothing. Trials on the initial state are remembered by ``key``."""
        first = self.Q.shape[1] == 0 and key is not None
        if first and key in self._first:
            return self._first[key]
        out = self._trial(basis)
        if first:
            self._first[key] = out
        return out

    def _trial(self, basis: np.ndarray):
        X = basis - self.Q @ (self.Q.T @ basis)
        X = X[:, np.linalg.norm(X, axis=0) > DEPENDENT]  # the columns had norm 1
        Qc = orthonormal_basis(X)
        k = Qc.shape[1]
        if k == 0 or self.dof - k <= 0:
            return None
        proj = Qc.T @ self.e
        ss = float(proj @ proj)
        _, pv = f_test(ss, k, self.rss - ss, self.dof - k)
        H = self.H + hat_blocks(Qc)
        return press_rms(self.e - Qc @ proj, H), pv, (Qc, proj, ss, H)

    def add(self, cv, pieces) -> None:
        Qc, proj, ss, H = pieces
        self.e = self.e - Qc @ proj
        self.rss, self.dof, self.H, self.cv = self.rss - ss, self.dof - Qc.shape[1], H, cv
        self.Q = np.hstack([self.Q, Qc])
