"""Block-wise evaluation of an error model over many poses, so that the lab's memory does not grow
with the Jacobian: 200,000 poses of the whole catalogue have a 340 MB Jacobian, and every copy of
it counted (issue 13).

The identification needs only small matrices built from it: the Gram matrix ``A^T A`` and
gradient ``A^T r`` of each Gauss-Newton step (sums over poses), and for identifiability the
triangular factor ``R`` of a QR decomposition (``A = Q R``: every inner product of the columns of
``A``, hence every quantity :func:`lab.identifiability.analyse` computes, is the same on ``R``),
accumulated block by block (TSQR: the R of ``[R_previous; A_block]``, Householder QR, backward
stable). Data sets of at most :data:`BLOCK` poses are one block, evaluated exactly as a single
array (the numbers do not depend on the blocking for them).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from arm.errormodel import ErrorModel, ModelInputs

if TYPE_CHECKING:
    from lab.observations import Observations

__all__ = ["Blocks"]

BLOCK = 4096  # poses per block: the Jacobian of 70 parameters is then 6.9 MB


class Blocks:
    """The inputs of ``model`` cut into consecutive blocks of at most ``size`` poses.

    With ``observations`` (:class:`lab.observations.Observations`, not plain) the blocks give
    the weighted rows a fit compares with, k per pose, instead of the points."""

    def __init__(
        self,
        model: ErrorModel,
        inputs: ModelInputs,
        size: int | None = None,
        observations: Observations | None = None,
    ) -> None:
        self.model, self.inputs = model, inputs
        self.obs = None if observations is None or observations.plain else observations
        size = BLOCK if size is None else size
        n = inputs.n
        self.slices = [slice(a, min(a + size, n)) for a in range(0, max(n, 1), size)]
        self.parts = (
            [inputs] if len(self.slices) == 1 else [inputs.subset(sl) for sl in self.slices]
        )

    @property
    def n(self) -> int:
        return self.inputs.n

    @property
    def single(self) -> bool:
        return len(self.slices) == 1

    def __iter__(self) -> Iterator[tuple[slice, ModelInputs]]:
        return iter(zip(self.slices, self.parts, strict=True))

    @property
    def per_pose(self) -> int:
        """Rows per pose: 3 (a point) or 6 (a point and an orientation)."""
        return 3 if self.obs is None else self.obs.per_pose

    def _rows(self, sl: slice, part: ModelInputs, p: np.ndarray, jacobian: bool):
        if self.obs is None:
            if jacobian:
                return self.model.predict(part, p, jacobian=True)
            return np.asarray(self.model.predict(part, p)), None
        return self.obs.rows(self.model, part, p, sl, jacobian)

    def predict(self, p: np.ndarray) -> np.ndarray:
        """Predicted points (N, 3), or rows (N, k) with observations."""
        if self.single:
            return self._rows(self.slices[0], self.inputs, p, False)[0]
        out = np.empty((self.n, self.per_pose))
        for sl, part in self:
            out[sl] = self._rows(sl, part, p, False)[0]
        return out

    def jacobians(
        self, p: np.ndarray, keep_cache: bool = True
    ) -> Iterator[tuple[slice, np.ndarray, np.ndarray]]:
        """Per block: its slice, the predicted points (n, 3) and the Jacobian (n, 3, P).
        ``keep_cache=False`` forgets each block's cached regressors once used (a single pass:
        kept for every block, they would grow with the pose count)."""
        for sl, part in self:
            pred, J = self._rows(sl, part, p, True)
            if not keep_cache and not self.single:
                part._cache.clear()
            yield sl, pred, J

    def r_factor(self, p: np.ndarray, columns: np.ndarray | None = None) -> np.ndarray:
        """The upper-triangular R (k, k) of a QR decomposition of the Jacobian (3N, k) at ``p``
        (its ``columns``, default all), accumulated block by block."""
        R: np.ndarray | None = None
        for _, _, J in self.jacobians(p):
            A = J.reshape(-1, J.shape[2]) if columns is None else J[:, :, columns]
            A = A.reshape(-1, A.shape[-1])
            stacked = A if R is None else np.vstack([R, A])
            # mode='r' returns the array R (numpy's stub types every mode as QRResult)
            R = np.asarray(np.linalg.qr(stacked, mode="r"))
        assert R is not None
        return R
