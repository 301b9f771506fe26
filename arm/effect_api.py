"""What an effect works with: the per-pose inputs it reads, the chain state it changes, the
sensitivities it builds its Jacobian columns from, and the error it raises.

    class MyEffect(JointAngleEffect):                     # arm.effects
        def basis(self, inputs: ModelInputs, joint, term):
            return inputs.column("temperature") - 20.0    # EffectError if the data lacks it

:class:`ModelInputs` (per data set: encoder readings, gravity torques, measured columns),
:class:`ChainState` (the DH arrays, base and tools as the chain effects leave them) and
:class:`Sensitivities` (derivatives of the measured point by the chain's quantities) are made by
:class:`arm.errormodel.ErrorModel` and handed to the effects of :mod:`arm.effects`; neither of
those two modules is imported here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from arm.description import RobotDescription
from arm.errors import EffectError
from arm.extra_joints import ExtraPlacement, place
from arm.kinematics import Chain, ColumnFrames, Workspace, cross_columns
from arm.so3 import left_jacobian

__all__ = [
    "REFERENCE_REACH",
    "AngularSensitivities",
    "ArmSize",
    "ChainState",
    "EffectError",
    "ModelInputs",
    "Sensitivities",
]

#: The size up to which an arm's plausible bounds keep their stated values, m of
#: :attr:`arm.description.RobotDescription.reach`: a UR10's (1.46 m) and the seed arm's
#: (1.50 m) with room to spare; a larger arm's length bounds grow in proportion.
REFERENCE_REACH = 1.6


@dataclass(frozen=True)
class ArmSize:
    """What an effect's plausible bounds may scale with (:meth:`arm.effects.Effect.plausible_bound`):
    the arm's ``reach`` (m, :attr:`arm.description.RobotDescription.reach`) and its ``payload``
    (kg, the description's; 0 where unknown).

    A length error of a machined arm grows with the arm (a casting of 1 m and one of 3 m are held
    to tolerances of the same relative size, and a data sheet rounds longer links more): the
    bound of a length is its stated value times :attr:`length_factor`, 1 up to the size of a
    UR10 (:data:`REFERENCE_REACH`), then in proportion to the reach (1.94 for a FANUC
    R-2000iC of 3.11 m). An angle's bound does not grow: a machined angle is held to the same
    tolerance at any size, and its effect on the tool already grows with the lever."""

    reach: float
    payload: float = 0.0

    @classmethod
    def of(cls, robot: RobotDescription) -> ArmSize:
        return cls(reach=robot.reach, payload=float(robot.payload))

    @property
    def length_factor(self) -> float:
        """How many times the stated bound a length of this arm may be off: 1 up to
        :data:`REFERENCE_REACH`, the reach over it beyond."""
        return max(1.0, self.reach / REFERENCE_REACH)


@dataclass
class ModelInputs:
    """Everything per pose that the model needs besides the parameters, computed once per data set.

    ``tau`` are the gravity torques of the nominal arm at the encoder reading (payload included,
    gravity as each pose's extra joints turn frame 0: ``gravity``);
    ``target`` is each pose's index into the model's targets, ``station`` into its stations.
    """

    robot: RobotDescription
    targets: tuple[int, ...]
    q: np.ndarray
    tau: np.ndarray
    target: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    station: np.ndarray | None = None
    _cache: dict = field(default_factory=dict, repr=False)
    # each pose's value of the robot's extra joints (N, k), SI (arm.extra_joints), or None
    extra: np.ndarray | None = None
    # each pose's gravity in frame 0 (N, 3), where extra joints turn it, or None (the robot's)
    gravity: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.station is None:
            self.station = np.zeros(self.q.shape[0], dtype=int)

    @property
    def stations(self) -> np.ndarray:
        """Each pose's index into the model's stations (N,)."""
        assert self.station is not None
        return self.station

    @property
    def n(self) -> int:
        return self.q.shape[0]

    def column(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise EffectError(
                f"column {name!r} is needed but the data has only: {', '.join(sorted(self.columns)) or 'q, x, y, z'}"
            ) from None

    def cached(self, owner: Any, fn: Callable[[ModelInputs], Any]) -> Any:
        """``fn(self)`` computed once per (owner, fn) for these inputs."""
        key = (id(owner), getattr(fn, "__qualname__", id(fn)))
        if key not in self._cache:
            self._cache[key] = fn(self)
        return self._cache[key]

    def subset(self, idx: np.ndarray | slice) -> ModelInputs:
        """The inputs of some poses only (for cross-validation and held-out tests)."""
        return ModelInputs(
            robot=self.robot,
            targets=self.targets,
            q=self.q[idx],
            tau=self.tau[idx],
            target=self.target[idx],
            columns={k: v[idx] for k, v in self.columns.items()},
            station=self.stations[idx],
            extra=None if self.extra is None else self.extra[idx],
            gravity=None if self.gravity is None else self.gravity[idx],
        )


@dataclass(frozen=True)
class ChainState:
    """The chain as the effects leave it: DH arrays, base transform, tool points per target.

    With several tracker stations, ``station_R``, ``station_t``, ``station_r`` hold each
    station's base (S, 3, 3), (S, 3), (S, 3) and ``base_*`` the first one's; with an orientation
    measured, ``tool_R`` and ``tool_r`` are the tool frame's rotation in the last frame (matrix and
    rotation vector)."""

    robot: RobotDescription
    targets: tuple[int, ...]
    chain: Chain
    base_R: np.ndarray
    base_t: np.ndarray
    base_r: np.ndarray
    tools: np.ndarray  # (n_targets, 3), in the last frame
    length_scale: np.ndarray | None = None  # (N,) product of length scalings (thermal)
    stations: tuple[int, ...] = (0,)
    orientation: bool = False
    # each station's session was re-homed: its own zero offsets (arm.effects.chain.Geometric)
    rehomed: bool = False
    station_R: np.ndarray | None = None
    station_t: np.ndarray | None = None
    station_r: np.ndarray | None = None
    tool_R: np.ndarray | None = None
    tool_r: np.ndarray | None = None
    # the robot's extra joints (arm.extra_joints): each pose's values (N, k), SI, and the
    # calibration's corrections, scale (k,) and tilt (k, 2); None without extra joints
    extra_values: np.ndarray | None = None
    extra_scale: np.ndarray | None = None
    extra_tilt: np.ndarray | None = None

    def pose_base(self, station: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """The base (R, t) of every pose: one (3, 3), (3,) for a single station, else per pose
        (N, 3, 3), (N, 3) from ``station`` (each pose's index into the stations); with extra
        joints, per pose through them (the arm's frame 0 in the measurement frame)."""
        if self.station_R is None or self.station_t is None or station is None:
            R, t = self.base_R, self.base_t
        else:
            R, t = self.station_R[station], self.station_t[station]
        extra = self.extra_placement()
        if extra is None:
            return R, t
        moved = extra.t @ R.T if R.ndim == 2 else np.einsum("nij,nj->ni", R, extra.t)
        return R @ extra.R, t + moved

    def extra_placement(self) -> ExtraPlacement | None:
        """The arm's frame 0 behind the extra joints at each pose's values, or None."""
        if self.extra_values is None or not self.robot.extra_joints:
            return None
        return place(
            self.robot.extra_joints,
            self.robot.mount_matrix,
            self.extra_values,
            self.extra_scale,
            self.extra_tilt,
        )

    def replace(self, **kw) -> ChainState:
        return replace(self, **kw)


class Sensitivities:
    """Elementary derivatives of the measured point, in the measurement frame, computed on first
    use from the frames of one evaluation.

    Component-major blocks, pose index last (what the catalogue's effects use): ``rows_alpha[i]``
    (3, N) is d p / d alpha of row i+1 (likewise ``rows_beta``, ``rows_a``, ``rows_theta``,
    ``rows_d``, all at the state's values), ``base_cols`` (6, 3, N) d p / d (bx, by, bz, brx, bry,
    brz) and ``tool_cols`` (3, 3, N) d p / d the tool point of the pose's own target. The same as
    (N, 3, k) views: ``d_alpha[:, :, i]``, ``d_beta``, ``d_a``, ``d_theta``, ``d_d``, ``d_base``,
    ``d_tool``.
    """

    def __init__(
        self,
        state: ChainState,
        frames: ColumnFrames,
        point: np.ndarray,
        work: Workspace | None = None,
        station: np.ndarray | None = None,
    ) -> None:
        self.state = state
        self._f = frames
        self._p = point  # (3, N), measurement frame
        self._new = (lambda name, shape: np.empty(shape)) if work is None else work
        self._station = station  # each pose's station index, with several stations

    @property
    def point(self) -> np.ndarray:
        """The measured point (3, N) of each pose, in the measurement frame."""
        return self._p

    @property
    def station(self) -> np.ndarray | None:
        """Each pose's station index where there are several stations, else None."""
        return self._station

    angular = False  # whether the columns are the tool frame's rotation (AngularSensitivities)

    @cached_property
    def _lever(self) -> np.ndarray:
        """p - o_i for frames 0..6, (7, 3, N)."""
        return np.subtract(self._p[None], self._f.o, out=self._new("sens.lever", self._f.o.shape))

    @cached_property
    def rows_alpha(self) -> np.ndarray:
        out = self._new("sens.alpha", self._f.x_a.shape)
        return cross_columns(self._f.axes[:6, 0], self._lever[:6], out=out)

    @cached_property
    def rows_beta(self) -> np.ndarray:
        return cross_columns(self._f.y_beta, self._lever[:6])

    def beta_rows(self, rows) -> np.ndarray:
        """``rows_beta[rows]``, computing only those rows."""
        if "rows_beta" in self.__dict__:
            return self.rows_beta[rows]
        return cross_columns(self._f.y_beta[rows], self._lever[:6][rows])

    @property
    def rows_a(self) -> np.ndarray:
        return self._f.x_a

    @cached_property
    def rows_theta(self) -> np.ndarray:
        out = self._new("sens.theta", self._f.x_a.shape)
        return cross_columns(self._f.axes[1:, 2], self._lever[1:], out=out)

    @property
    def rows_d(self) -> np.ndarray:
        return self._f.axes[1:, 2]

    @cached_property
    def rows_joint(self) -> np.ndarray:
        """d p / d q_j (6, 3, N), the controller's joint angles: ``rows_theta`` where each joint
        is its own, through the coupling (``theta = C q``) where joints are coupled. What a
        joint-angle effect, which moves the controller's angle, writes its columns from."""
        C = self.state.chain.coupling
        if C is None:
            return self.rows_theta
        return np.einsum("ij,ixn->jxn", C, self.rows_theta)

    def _base_rotation_columns(self) -> tuple[np.ndarray, np.ndarray]:
        """J_l(r) of the base rotation as columns (3 j, 3, 1 or N) and the base translation
        (3, 1 or N), of each pose's station."""
        st = self.state
        if st.station_r is None or st.station_t is None or self._station is None:
            return left_jacobian(st.base_r).T[:, :, None], st.base_t[:, None]
        Jl = np.stack([left_jacobian(r) for r in st.station_r])  # (S, 3, 3)
        return Jl[self._station].transpose(2, 1, 0), st.station_t[self._station].T

    @cached_property
    def base_cols(self) -> np.ndarray:
        out = np.zeros((6, 3, self._p.shape[1]))
        out[0, 0] = out[1, 1] = out[2, 2] = 1.0
        # d(R(r) p_b)/dr = -[R p_b]x J_l(r): column j is J_l[:, j] x (p - t_b)
        Jl, t = self._base_rotation_columns()
        out[3:] = cross_columns(Jl, (self._p - t)[None])
        return out

    @property
    def tool_cols(self) -> np.ndarray:
        return self._f.axes[6]

    @cached_property
    def tool_rotation_cols(self) -> np.ndarray:
        """d / d (trx, try, trz), the tool frame's rotation: the tool point does not move."""
        return np.zeros((3, 3, self._p.shape[1]))

    d_alpha = property(lambda self: self.rows_alpha.transpose(2, 1, 0))
    d_beta = property(lambda self: self.rows_beta.transpose(2, 1, 0))
    d_a = property(lambda self: self.rows_a.transpose(2, 1, 0))
    d_theta = property(lambda self: self.rows_theta.transpose(2, 1, 0))
    d_joint = property(lambda self: self.rows_joint.transpose(2, 1, 0))
    d_d = property(lambda self: self.rows_d.transpose(2, 1, 0))
    d_base = property(lambda self: self.base_cols.transpose(2, 1, 0))
    d_tool = property(lambda self: self.tool_cols.transpose(2, 1, 0))


class AngularSensitivities(Sensitivities):
    """The same derivatives for the tool frame's orientation: each column is the small rotation
    (rad, about the measurement frame's axes) that a unit change of the chain's quantity turns
    the tool frame by, ``R(p + dp) = exp([w dp]x) R(p)``. Where :class:`Sensitivities` gives the
    point's velocity ``v + w x (p - o)`` of a joint's twist, this gives its ``w``: the axis of
    alpha, beta or theta, nothing for a, d or the tool point. The catalogue's effects write their
    orientation columns from these, with the code that writes their position columns."""

    angular = True

    def _zeros(self, shape: tuple[int, ...]) -> np.ndarray:
        return np.zeros(shape)

    @cached_property
    def rows_alpha(self) -> np.ndarray:
        return self._f.axes[:6, 0]

    @cached_property
    def rows_beta(self) -> np.ndarray:
        return self._f.y_beta

    def beta_rows(self, rows) -> np.ndarray:
        return self._f.y_beta[rows]

    @cached_property
    def rows_a(self) -> np.ndarray:
        return self._zeros(self._f.x_a.shape)

    @cached_property
    def rows_theta(self) -> np.ndarray:
        return self._f.axes[1:, 2]

    @cached_property
    def rows_d(self) -> np.ndarray:
        return self._zeros(self._f.x_a.shape)

    @cached_property
    def base_cols(self) -> np.ndarray:
        out = np.zeros((6, 3, self._p.shape[1]))
        out[3:] = self._base_rotation_columns()[0]
        return out

    @cached_property
    def tool_cols(self) -> np.ndarray:
        return self._zeros((3, 3, self._p.shape[1]))

    @cached_property
    def tool_rotation_cols(self) -> np.ndarray:
        # R = R6 exp(tr): exp(tr + d) = exp(J_l(tr) d) exp(tr), turned into the measurement
        # frame by R6: column j is R6 J_l(tr)[:, j]
        tr = self.state.tool_r
        Jl = left_jacobian(np.zeros(3) if tr is None else tr)
        return np.einsum("kcn,kj->jcn", self._f.axes[6], Jl)
