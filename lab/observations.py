"""What a fit compares the model with: one row per measured component of each pose, weighted by
the instrument's uncertainty (docs/format.md, the measurement CSV).

    obs = observations_of(data, options)          # from the data and the instrument model
    pred, J = obs.rows(model, inputs, p, sl)       # a block of poses: rows (n, k), (n, k, P)
    r = pred - obs.target[sl]                      # the residual rows

A pose measured as a point gives three rows (x, y, z); one whose orientation was measured too gives
six, the last three the rotation ``e = log(R_model R_measured^T)`` (rad, about the measurement
frame's axes; 0 measured, so the target is 0), with its Jacobian ``J_l(e)^-1 w`` from the model's
rotation columns ``w`` (:meth:`arm.errormodel.ErrorModel.predict_pose`).

**Weights.** Where the rows' uncertainties differ (``std_*`` columns, ``--noise-ppm``, an
orientation), each row is multiplied by ``sigma_ref / sigma``: every row then has the same noise,
``sigma_ref`` (the RMS of the positions' sigmas), in metres, and every statistic of the lab (the
fit, the identifiability's noise criterion, standard errors, the outlier rule, the diagnosis's
F- and chi-square tests, the discovery's stopping rule) holds as written for one per-axis noise.
A component a row did not measure has weight 0 (its rows are zero and not counted as equations).
Positions alone with one sigma (or none stated) are the plain case: the rows are the points, as
they always were, to the last bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from arm.effect_api import ModelInputs
from arm.errormodel import ErrorModel
from arm.measurements import COMPONENTS, MeasurementSet
from arm.noise import InstrumentNoise
from arm.so3 import left_jacobian_inverse, rotation_matrix, rotation_vector
from lab.errors import FitError

__all__ = ["Observations", "observations_of"]


@dataclass(frozen=True)
class Observations:
    """The measured rows of a data set: ``xyz`` (N, 3); ``rotation`` (N, 3, 3), the measured
    orientations, or None for positions alone; ``scale`` (N, k), each row's weight
    ``sigma_ref / sigma`` (0 where not measured), or None where every row weighs 1;
    ``sigma_ref`` (m), the per-row noise after weighting, or None where no uncertainty is
    stated; ``sigma`` (N, k) the rows' own (m, rad), or None."""

    xyz: np.ndarray
    rotation: np.ndarray | None = None
    scale: np.ndarray | None = None
    sigma_ref: float | None = None
    sigma: np.ndarray | None = None

    @property
    def per_pose(self) -> int:
        return 3 if self.rotation is None else 6

    @property
    def plain(self) -> bool:
        """Positions alone, every row weighing 1: the rows are the points."""
        return self.rotation is None and self.scale is None

    @property
    def n(self) -> int:
        return len(self.xyz)

    @property
    def measured(self) -> np.ndarray:
        """(N, k) which rows were measured."""
        if self.scale is None:
            return np.ones((self.n, self.per_pose), dtype=bool)
        return self.scale > 0

    @property
    def n_equations(self) -> int:
        """The measured rows: the equations of a fit."""
        return int(self.measured.sum())

    @property
    def target(self) -> np.ndarray:
        """The measured rows (N, k), weighted: the points, then 0 for a rotation's error."""
        t = self.xyz
        if self.rotation is not None:
            t = np.concatenate([t, np.zeros((self.n, 3))], axis=1)
        return t if self.scale is None else t * self.scale

    def subset(self, idx: np.ndarray | slice) -> Observations:
        def rows(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[idx]

        return Observations(
            self.xyz[idx], rows(self.rotation), rows(self.scale), self.sigma_ref, rows(self.sigma)
        )

    def rows(
        self,
        model: ErrorModel,
        inputs: ModelInputs,
        p: np.ndarray,
        sl: slice | None = None,
        jacobian: bool = True,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The model's rows (n, k) and, with ``jacobian``, their derivatives (n, k, P), weighted,
        for the poses ``sl`` of the data (``inputs`` are theirs)."""
        sl = slice(None) if sl is None else sl
        if self.rotation is None:
            if jacobian:
                pred, J = model.predict(inputs, p, jacobian=True)
            else:
                pred, J = model.predict(inputs, p), None
        else:
            if jacobian:
                x, R, JP, JW = model.predict_pose(inputs, p, jacobian=True)
            else:
                x, R = model.predict_pose(inputs, p)
            seen = self.measured[sl][:, 3:].any(axis=1)
            e = rotation_vector(R @ self.rotation[sl].transpose(0, 2, 1))
            e[~seen] = 0.0  # an orientation not measured: its rows weigh 0
            pred = np.concatenate([x, e], axis=1)
            J = None
            if jacobian:
                J = np.concatenate([JP, left_jacobian_inverse(e) @ JW], axis=1)
        if self.scale is not None:
            s = self.scale[sl]
            pred = pred * s
            if J is not None:
                J = J * s[:, :, None]
        return pred, J

    def joint_rows(
        self, model: ErrorModel, inputs: ModelInputs, p: np.ndarray, sl: slice | None = None
    ) -> np.ndarray:
        """The rows' derivatives by the six effective joint angles (n, k, 6), weighted: what
        a joint-angle error that depends on a measured variable does to them."""
        sl = slice(None) if sl is None else sl
        _, Jq = model.joint_jacobian(inputs, p)
        if self.rotation is not None:
            _, R = model.predict_pose(inputs, p)
            seen = self.measured[sl][:, 3:].any(axis=1)
            e = rotation_vector(R @ self.rotation[sl].transpose(0, 2, 1))
            e[~seen] = 0.0
            Jq = np.concatenate([Jq, left_jacobian_inverse(e) @ model.joint_turns(inputs, p)], 1)
        return Jq if self.scale is None else Jq * self.scale[sl][:, :, None]

    def orientation_errors(
        self, model: ErrorModel, inputs: ModelInputs, p: np.ndarray
    ) -> np.ndarray:
        """The rotation (N, 3) from the measured orientation to the model's, rad, unweighted;
        NaN in the rows that measured none."""
        if self.rotation is None:
            return np.full((self.n, 3), np.nan)
        _, R = model.predict_pose(inputs, p)
        e = rotation_vector(R @ self.rotation.transpose(0, 2, 1))
        e[~self.measured[:, 3:].any(axis=1)] = np.nan
        return e


def orientation_stated(data: MeasurementSet, noise: InstrumentNoise | None) -> bool:
    """Whether the orientations' uncertainty is stated: ``--noise-mrad`` or std_rx.. cells."""
    if noise is not None and noise.mrad is not None:
        return True
    return data.std is not None and bool(np.isfinite(data.std[:, 3:]).any())


def uses_orientation(
    data: MeasurementSet,
    measured: tuple[str, ...] | None,
    noise: InstrumentNoise | None = None,
) -> bool:
    """Whether a fit of ``data`` uses orientation rows: the data measured some, and
    ``measured`` names one of rx, ry, rz; by default (``measured`` None) where the
    orientations' uncertainty is stated (without it they cannot be weighed against the
    positions: the positions alone are fitted, and the fit warns)."""
    if not data.has_orientation:
        return False
    if measured is None:
        return orientation_stated(data, noise)
    return bool(set(measured) & {"rx", "ry", "rz"})


def observations_of(
    data: MeasurementSet,
    noise: InstrumentNoise | None = None,
    measured: tuple[str, ...] | None = None,
) -> Observations:
    """The rows a fit of ``data`` compares with: positions, orientations where ``measured``
    allows and the data have them, weighted by ``noise`` and the rows' own ``std_*``
    (see the module docstring). Orientation rows need their uncertainty and the positions'
    stated (``--noise-mm``/``std_x..`` and ``--noise-mrad``/``std_rx..``): without them there is no
    weighing a radian against a metre."""
    noise = noise or InstrumentNoise()
    turn = uses_orientation(data, measured, noise)
    k = 6 if turn else 3
    mask = data.measured[:, :k].copy()
    if measured is not None:
        mask &= np.array([c in measured for c in COMPONENTS[:k]])
    sig = noise.sigmas(data)[:, :k]
    pos = sig[:, :3]
    stated_pos = bool(np.isfinite(pos).all())
    if not turn:
        if not stated_pos:
            return Observations(data.xyz)
        ref = float(pos.flat[0])
        if np.all(pos == ref):  # one sigma for every row: the plain case, noise known
            return Observations(data.xyz, sigma_ref=ref, sigma=sig)
        ref = float(math.sqrt(np.mean(pos**2)))
        return Observations(data.xyz, scale=ref / pos, sigma_ref=ref, sigma=sig)
    rot = sig[:, 3:]
    missing = []
    if not stated_pos:
        missing.append("the positions' (--noise-mm, or std_x, std_y, std_z)")
    if np.isnan(rot[mask[:, 3:]]).any():
        missing.append("the orientations' (--noise-mrad, or std_rx, std_ry, std_rz)")
    if missing:
        raise FitError(
            f"{data.source}: orientation rows are weighed against positions by their "
            f"uncertainties: state {' and '.join(missing)}; or fit the positions alone "
            "(--measured x,y,z)"
        )
    ref = float(pos.flat[0]) if np.all(pos == pos.flat[0]) else float(math.sqrt(np.mean(pos**2)))
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(mask, ref / np.where(mask, sig, 1.0), 0.0)
    assert data.orientation is not None
    return Observations(
        data.xyz, rotation_matrix(data.orientation), scale, ref, np.where(mask, sig, np.nan)
    )
