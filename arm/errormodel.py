"""The pose-error model: a robot description plus a list of effects, predicting the measured tool
point of every pose and the identification Jacobian (derivatives by every named parameter).

    model = ErrorModel(seed_robot(), "geometric,compliance")
    inputs = model.inputs(q, columns)          # per data set: gravity torques, directions, ...
    p = model.nominal()                        # a vector laid out by model.layout
    xyz, J = model.predict(inputs, p, jacobian=True)   # (N, 3), (N, 3, P)

Prediction: joint-angle effects change theta at the encoder reading q; chain effects change the
DH table (geometric errors first, then thermal scaling); the tool point of each pose's target goes
through the frames and the base transform (of the pose's tracker station) into the measurement
frame. A model built with ``orientation=True`` also predicts the tool frame's rotation
(:meth:`ErrorModel.predict_pose`), whose Jacobian columns the effects write with the same code,
from :class:`arm.effect_api.AngularSensitivities`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Literal, overload

import numpy as np

from arm.description import RobotDescription, vec3
from arm.effect_api import (
    AngularSensitivities,
    ChainState,
    EffectError,
    ModelInputs,
    Sensitivities,
)
from arm.effects import (
    ChainEffect,
    Effect,
    Geometric,
    JointAngleEffect,
    check_robot_effects,
    effect_origin,
    is_catalogued,
    parse_effects,
    user_code,
)
from arm.errors import ModelError
from arm.extra_joints import extra_values
from arm.kinematics import (
    Chain,
    ColumnFrames,
    Workspace,
    column_frames,
    gravity_torques,
    tool_points,
)
from arm.params import TOOL_ROTATION_NAMES, ParameterLayout
from arm.so3 import rotation_vector

__all__ = ["ErrorModel"]

log = logging.getLogger(__name__)


def _finite(
    effect: Effect,
    what: str,
    values: np.ndarray,
    shape: tuple[int, ...],
    all_effects: Sequence[Effect] = (),
) -> None:
    """Refuse what a user's effect gave (``values``) unless it has ``shape`` and is finite: NaN
    from a user's code would end the fit in an SVD that does not converge, far from its cause."""
    if values.shape != shape:
        raise EffectError(
            f"{effect_origin(effect)}: {what} returned shape {values.shape}, not {shape}"
        )
    if not np.all(np.isfinite(values)):
        users = [e for e in all_effects if not is_catalogued(e)] or [effect]
        who = ", ".join(effect_origin(e) for e in users)
        raise EffectError(f"{who}: {what} gave NaN or infinity")


def _index_of_ids(values: np.ndarray, ids: tuple[int, ...], what: str, source: str) -> np.ndarray:
    """Each of ``values``' index into the model's ``ids`` (its targets or stations); an
    EffectError names the ``what`` id(s) among ``values`` that the model does not have."""
    arr = np.array(ids)
    order = np.argsort(arr)
    pos = np.clip(np.searchsorted(arr[order], values), 0, len(arr) - 1)
    found = arr[order][pos] == values
    if not found.all():
        unknown = sorted({int(v) for v in values[~found]})
        raise EffectError(f"{source}: {what} id(s) {unknown} not among the model's {ids}")
    return order[pos]


def _central_differences(
    p: np.ndarray, sl: slice, n: int, difference: Callable[[np.ndarray, np.ndarray], np.ndarray]
) -> np.ndarray:
    """``difference(p + h, p - h) / 2h`` (N, 3) for each parameter ``k`` of ``sl`` (``h`` on
    ``p[k]`` alone, relative to its size), stacked on the last axis: (N, 3, k)."""
    cols = []
    for k in range(sl.start, sl.stop):
        h = 1e-6 * max(1.0, abs(p[k]))
        pp, pm = p.copy(), p.copy()
        pp[k] += h
        pm[k] -= h
        cols.append(difference(pp, pm) / (2 * h))
    return np.stack(cols, axis=-1) if cols else np.empty((n, 3, 0))


class ErrorModel:
    """A robot description with a list of effects; see the module docstring."""

    def __init__(
        self,
        robot: RobotDescription,
        effects: str | Sequence[str | Effect] = "geometric",
        targets: Sequence[int] = (0,),
        stations: Sequence[int] = (0,),
        orientation: bool = False,
        rehomed: bool = False,
    ) -> None:
        self.robot = robot.to_modified()
        self.described = robot  # as its file states it (its own DH convention), for messages
        if robot.effects:
            check_robot_effects(self.robot)
        self.effects: list[Effect] = parse_effects(effects)
        self.targets = tuple(int(t) for t in targets)
        if not self.targets or len(set(self.targets)) != len(self.targets):
            raise ModelError(f"targets must be distinct ids, got {targets}")
        self.stations = tuple(int(s) for s in stations)
        if not self.stations or len(set(self.stations)) != len(self.stations):
            raise ModelError(f"stations must be distinct ids, got {stations}")
        self.orientation = bool(orientation)
        # each station's session was re-homed: its own joint zero offsets (Geometric)
        self.rehomed = bool(rehomed) and len(self.stations) > 1
        geometric = any(isinstance(e, Geometric) for e in self.effects)
        if (len(self.stations) > 1 or self.orientation) and not geometric:
            raise EffectError(
                "several stations or a measured orientation need the geometric effect (it "
                "holds each station's base and the tool frame's rotation)"
            )
        groups = []
        for e in self.effects:
            with user_code(e, "parameter_names"):
                groups.append((e.name, list(self._names(e))))
        try:
            self.layout = ParameterLayout.of(groups)
        except ValueError as exc:  # two effects name one parameter alike
            raise EffectError(f"effects {', '.join(self.effect_names)}: {exc}") from None
        # a user's effect is checked where it runs: its failure is one line naming it
        self._user = any(not is_catalogued(e) for e in self.effects)
        self._chain0 = Chain.from_description(self.robot)
        self._base_R0 = self.robot.base_matrix[:3, :3]
        self._work = Workspace()  # scratch of predict(jacobian=True), reused between calls
        tools = self.robot.tool_points
        self._tools0 = np.array(
            [tools[k] if k < len(tools) else tools[0] for k in range(len(self.targets))]
        )
        self._joint_effects = [e for e in self.effects if isinstance(e, JointAngleEffect)]
        self._chain_effects = sorted(
            (e for e in self.effects if isinstance(e, ChainEffect)), key=lambda e: e.order
        )
        other = [e for e in self.effects if not isinstance(e, JointAngleEffect | ChainEffect)]
        if other:
            raise EffectError(f"effects {other} are neither joint-angle nor chain effects")

    def _names(self, e: Effect) -> list[str]:
        if isinstance(e, Geometric):
            return e.parameter_names(
                self.robot, self.targets, self.stations, self.orientation, self.rehomed
            )
        return e.parameter_names(self.robot, self.targets)

    def __repr__(self) -> str:
        return f"ErrorModel({self.robot.name!r}, {[e.label for e in self.effects]}, {len(self.layout)} parameters)"

    @property
    def effect_names(self) -> list[str]:
        return [e.label for e in self.effects]

    def with_effects(self, effects: str | Sequence[str | Effect]) -> ErrorModel:
        return ErrorModel(
            self.robot, effects, self.targets, self.stations, self.orientation, self.rehomed
        )

    def required_columns(self) -> set[str]:
        return {c for e in self.effects for c in e.columns}

    def nominal(self) -> np.ndarray:
        """The parameter vector of the description itself (no error)."""
        return np.concatenate(
            [e.nominal(self.robot, self.layout.groups[k][1]) for k, e in enumerate(self.effects)]
        )

    # -- inputs ------------------------------------------------------------------------------
    def inputs(
        self,
        q: np.ndarray,
        columns: Mapping[str, np.ndarray] | None = None,
        source: str = "data",
    ) -> ModelInputs:
        """Per-pose inputs. ``columns`` may hold t, temperature, payload, dir1..6, target, others."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if q.ndim != 2 or q.shape[1] != 6:
            raise ModelError(f"{source}: joint angles must have shape (N, 6), got {q.shape}")
        cols = {k: np.asarray(v, dtype=float) for k, v in (columns or {}).items()}
        missing = sorted(c for c in self.required_columns() if c not in cols)
        if missing:
            needs = {c: [e.name for e in self.effects if c in e.columns] for c in missing}
            detail = "; ".join(f"{c} (needed by {', '.join(v)})" for c, v in needs.items())
            raise EffectError(f"{source}: missing column(s) {detail}")
        extra = (
            extra_values(self.robot.extra_joints, cols, q.shape[0], source, self.robot.source)
            if self.robot.extra_joints
            else None
        )
        # the gravity frame 0 feels where extra joints turn it (a tilting table), nominal values
        gravity = None if extra is None else self.robot.frame0_gravity(extra)
        tau = gravity_torques(self.robot, q, payload=cols.get("payload"), gravity=gravity)
        if "target" in cols:
            t = cols["target"]
            if np.any(t != np.round(t)):
                raise EffectError(f"{source}: target ids must be integers")
            target = _index_of_ids(t, self.targets, "target", source)
        else:
            if len(self.targets) > 1:
                raise EffectError(
                    f"{source}: the model has several targets but the data no 'target' column"
                )
            target = np.zeros(q.shape[0], dtype=int)
        station = self._station_index(cols, q.shape[0], source)
        return ModelInputs(
            self.robot, self.targets, q, tau, target, cols, station, extra=extra, gravity=gravity
        )

    def _station_index(self, cols: Mapping[str, np.ndarray], n: int, source: str) -> np.ndarray:
        """Each pose's index into the model's stations, from the ``station`` column."""
        if "station" not in cols or len(self.stations) == 1:
            if len(self.stations) > 1:
                raise EffectError(
                    f"{source}: the model has several stations but the data no 'station' column"
                )
            if "station" in cols and np.any(cols["station"] != self.stations[0]):
                other = sorted({int(v) for v in cols["station"]} - {self.stations[0]})
                raise EffectError(
                    f"{source}: station id(s) {other} not among the model's {self.stations}"
                )
            return np.zeros(n, dtype=int)
        return _index_of_ids(cols["station"], self.stations, "station", source)

    # -- evaluation ---------------------------------------------------------------------------
    def _values(self, p: np.ndarray, effect: Effect) -> np.ndarray:
        return p[self.layout.slice(effect.name)]

    def joint_angles(self, inputs: ModelInputs, p: np.ndarray) -> np.ndarray:
        """The effective joint angles (N, 6): encoder reading plus every joint-angle effect."""
        theta = inputs.q.copy()
        for e in self._joint_effects:
            if self._user:
                with user_code(e, "joint_offsets"):
                    d = np.asarray(e.joint_offsets(inputs, self._values(p, e)), dtype=float)
                _finite(e, "joint_offsets", d, (inputs.n, 6))
                theta += d
            else:
                theta += e.joint_offsets(inputs, self._values(p, e))
        return theta

    def state(self, inputs: ModelInputs | None, p: np.ndarray) -> ChainState:
        """The chain after every chain effect (``inputs`` may be None without per-pose effects)."""
        st = self._initial_state(inputs)
        for e in self._chain_effects:
            if self._user:
                with user_code(e, "apply"):
                    st = e.apply(inputs, self._values(p, e), st)
                if not isinstance(st, ChainState):
                    raise EffectError(
                        f"{effect_origin(e)}: apply returned {st!r:.40}, not a ChainState"
                    )
            else:
                st = e.apply(inputs, self._values(p, e), st)
        return st

    def _initial_state(self, inputs: ModelInputs | None = None) -> ChainState:
        return ChainState(
            robot=self.robot,
            targets=self.targets,
            chain=self._chain0,
            base_R=self._base_R0,
            base_t=np.array(self.robot.base_translation, dtype=float),
            base_r=np.array(self.robot.base_rotation, dtype=float),
            tools=self._tools0.copy(),
            stations=self.stations,
            orientation=self.orientation,
            rehomed=self.rehomed,
            extra_values=None if inputs is None else inputs.extra,
        )

    def _evaluate(
        self, inputs: ModelInputs, p: np.ndarray, work: Workspace | None = None
    ) -> tuple[ChainState, ColumnFrames]:
        """The chain state and its frames in the measurement frame (component-major)."""
        theta = self.joint_angles(inputs, p)
        st = self.state(inputs, p)
        R, t = st.pose_base(self._pose_stations(inputs))
        return st, column_frames(st.chain, theta, R, t, work)

    def _pose_stations(self, inputs: ModelInputs) -> np.ndarray | None:
        """Each pose's station index where there are several stations, else None."""
        return inputs.stations if len(self.stations) > 1 else None

    @staticmethod
    def _point(st: ChainState, f: ColumnFrames, target: np.ndarray) -> np.ndarray:
        """The measured point (3, N) of each pose's target."""
        tool = st.tools.T[:, target] if len(st.tools) > 1 else st.tools[0][:, None]
        p = f.o[6] + f.axes[6, 0] * tool[0]
        p += f.axes[6, 1] * tool[1]
        p += f.axes[6, 2] * tool[2]
        return p

    @overload
    def predict(
        self, inputs: ModelInputs, p: np.ndarray, jacobian: Literal[False] = False
    ) -> np.ndarray: ...

    @overload
    def predict(
        self, inputs: ModelInputs, p: np.ndarray, jacobian: Literal[True]
    ) -> tuple[np.ndarray, np.ndarray]: ...

    @overload
    def predict(
        self, inputs: ModelInputs, p: np.ndarray, jacobian: bool
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]: ...

    def predict(
        self, inputs: ModelInputs, p: np.ndarray, jacobian: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Measured points (N, 3); with ``jacobian=True`` also d points / d p (N, 3, P)."""
        p = np.asarray(p, dtype=float)
        if p.shape != (len(self.layout),):
            raise ModelError(f"expected {len(self.layout)} parameters, got shape {p.shape}")
        if not jacobian:
            theta = self.joint_angles(inputs, p)
            st = self.state(inputs, p)
            tool = st.tools[inputs.target] if len(st.tools) > 1 else st.tools[0]
            R, t = st.pose_base(self._pose_stations(inputs))
            if R.ndim == 3:
                out = np.einsum("nij,nj->ni", R, tool_points(st.chain, theta, tool)) + t
            else:
                out = tool_points(st.chain, theta, tool) @ R.T + t
            if self._user:
                _finite(self.effects[-1], "apply", out, out.shape, all_effects=self.effects)
            return out
        st, f = self._evaluate(inputs, p, self._work)
        point = self._point(st, f, inputs.target)
        if self._user:
            _finite(self.effects[-1], "apply", point, point.shape, all_effects=self.effects)
        sens = Sensitivities(st, f, point, self._work, self._pose_stations(inputs))
        JT = self._columns(inputs, p, sens, "jacobian", self._numeric_columns)
        return point.T.copy(), np.ascontiguousarray(JT.transpose(2, 1, 0))

    def _columns(self, inputs, p, sens, name: str, numeric) -> np.ndarray:
        """Every effect's columns, component-major (P, 3, N), from ``sens`` (a workspace array
        ``name``); ``numeric(inputs, p, slice)`` (N, 3, k) for an effect without analytic ones."""
        # columns are built component-major, (P, 3, N), then laid out as (N, 3, P) once
        JT = self._work(name, (len(self.layout), 3, inputs.n))
        for e in self.effects:
            sl = self.layout.slice(e.name)
            v = p[sl]
            with user_code(e, "jacobian"):
                if isinstance(e, JointAngleEffect):
                    e.jacobian_into(inputs, v, sens, JT[sl])
                elif not isinstance(e, ChainEffect):
                    raise EffectError(
                        f"effect {e.name!r} is neither a joint-angle nor a chain effect"
                    )
                elif not e.jacobian_into(inputs, v, sens, JT[sl]):
                    JT[sl] = numeric(inputs, p, sl).transpose(2, 1, 0)
            if self._user and not is_catalogued(e):
                _finite(e, "jacobian", JT[sl], JT[sl].shape)
        return JT

    @overload
    def predict_pose(
        self, inputs: ModelInputs, p: np.ndarray, jacobian: Literal[False] = False
    ) -> tuple[np.ndarray, np.ndarray]: ...

    @overload
    def predict_pose(
        self, inputs: ModelInputs, p: np.ndarray, jacobian: Literal[True]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]: ...

    def predict_pose(self, inputs: ModelInputs, p: np.ndarray, jacobian: bool = False):
        """The measured points (N, 3) and the tool frame's rotation (N, 3, 3), measurement frame
        <- tool frame (the last frame turned by the tool rotation ``trx try trz`` where the
        model has one); with ``jacobian=True`` also d points / d p (N, 3, P) and the rotation's
        derivatives (N, 3, P): column k is the small rotation w (rad, about the measurement
        frame's axes) with R(p + e_k h) = exp([w h]x) R(p) to first order in h."""
        p = np.asarray(p, dtype=float)
        if p.shape != (len(self.layout),):
            raise ModelError(f"expected {len(self.layout)} parameters, got shape {p.shape}")
        st, f = self._evaluate(inputs, p, self._work if jacobian else None)
        point = self._point(st, f, inputs.target)
        R = f.axes[6].transpose(2, 1, 0)  # (N, 3, 3): column k is axis k of the last frame
        if st.tool_R is not None:
            R = R @ st.tool_R
        else:
            R = R.copy()
        if not jacobian:
            return point.T.copy(), R
        station = self._pose_stations(inputs)
        sens = Sensitivities(st, f, point, self._work, station)
        JP = self._columns(inputs, p, sens, "jacobian", self._numeric_columns)
        JP = np.ascontiguousarray(JP.transpose(2, 1, 0))
        turn = AngularSensitivities(st, f, point, None, station)
        JW = self._columns(inputs, p, turn, "jacobian.turn", self._numeric_turns)
        return point.T.copy(), R, JP, np.ascontiguousarray(JW.transpose(2, 1, 0))

    def joint_jacobian(self, inputs: ModelInputs, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measured points (N, 3) and their derivatives by the effective joint angles theta
        (N, 3, 6, the controller's angles where joints are coupled), in the measurement frame:
        the step direction of inverse kinematics on the calibrated model
        (:func:`arm.ik.solve_position`)."""
        st, f = self._evaluate(inputs, np.asarray(p, dtype=float))
        point = self._point(st, f, inputs.target)
        sens = Sensitivities(st, f, point, None, self._pose_stations(inputs))
        return point.T.copy(), np.ascontiguousarray(sens.d_joint)

    def joint_turns(self, inputs: ModelInputs, p: np.ndarray) -> np.ndarray:
        """The tool frame's rotation by each effective joint angle (N, 3, 6): joint i's axis in
        the measurement frame (:meth:`joint_jacobian`'s companion for orientations)."""
        st, f = self._evaluate(inputs, np.asarray(p, dtype=float))
        turn = AngularSensitivities(st, f, f.o[6], None, self._pose_stations(inputs))
        return np.ascontiguousarray(turn.d_joint)

    def joint_pose_jacobian(
        self, inputs: ModelInputs, p: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The measured points (N, 3) and the tool frame's rotation (N, 3, 3), as
        :meth:`predict_pose`, with their derivatives by the effective joint angles: d points
        (N, 3, 6) and the small rotations (N, 3, 6) of :meth:`joint_jacobian` and
        :meth:`joint_turns`, from one evaluation of the chain (inverse kinematics of a pose)."""
        st, f = self._evaluate(inputs, np.asarray(p, dtype=float))
        point = self._point(st, f, inputs.target)
        R = f.axes[6].transpose(2, 1, 0)
        R = R @ st.tool_R if st.tool_R is not None else R.copy()
        station = self._pose_stations(inputs)
        sens = Sensitivities(st, f, point, None, station)
        turn = AngularSensitivities(st, f, f.o[6], None, station)
        return (
            point.T.copy(),
            R,
            np.ascontiguousarray(sens.d_joint),
            np.ascontiguousarray(turn.d_joint),
        )

    def _numeric_columns(self, inputs: ModelInputs, p: np.ndarray, sl: slice) -> np.ndarray:
        """Central differences for an effect without analytic columns."""

        def moved(pp: np.ndarray, pm: np.ndarray) -> np.ndarray:
            return self.predict(inputs, pp) - self.predict(inputs, pm)

        return _central_differences(p, sl, inputs.n, moved)

    def _numeric_turns(self, inputs: ModelInputs, p: np.ndarray, sl: slice) -> np.ndarray:
        """Central differences of the tool frame's rotation, as small rotations (N, 3, k)."""

        def turned(pp: np.ndarray, pm: np.ndarray) -> np.ndarray:
            Rp = self.predict_pose(inputs, pp)[1]
            Rm = self.predict_pose(inputs, pm)[1]
            return rotation_vector(Rp @ Rm.transpose(0, 2, 1))

        return _central_differences(p, sl, inputs.n, turned)

    # -- a calibrated arm as a description -----------------------------------------------------
    def description(self, p: np.ndarray, name: str | None = None) -> RobotDescription:
        """The arm with the parameters ``p`` folded in: a description that reproduces this model's
        predictions with zero errors (non-geometric effect values go to ``effects``)."""
        st = self._initial_state()
        for ce in self._chain_effects:  # per-pose effects (thermal) stay effects, not geometry
            if not ce.columns:
                st = ce.apply(None, self._values(p, ce), st)
        ch = st.chain
        joints = tuple(
            replace(
                j,
                alpha=float(ch.alpha[i]),
                a=float(ch.a[i]),
                d=float(ch.d[i]),
                theta_offset=float(ch.theta_offset[i]),
                beta=float(ch.beta[i]),
            )
            for i, j in enumerate(self.robot.joints)
        )
        effects = dict(self.robot.effects)
        if st.tool_r is not None:  # a 6-DoF calibration's tool frame, which DH cannot hold
            effects["geometric"] = effects.get("geometric", {}) | dict(
                zip(TOOL_ROTATION_NAMES, map(float, st.tool_r), strict=True)
            )
        for e in self.effects:
            if e.name != "geometric":
                names = self.layout.names[self.layout.slice(e.name)]
                effects[e.name] = effects.get(e.name, {}) | dict(
                    zip(names, map(float, self._values(p, e)), strict=True)
                )
        return replace(
            self.robot,
            name=name or f"{self.robot.name}-calibrated",
            joints=joints,
            tools=tuple(vec3(t) for t in st.tools),
            base_translation=vec3(st.base_t),
            base_rotation=vec3(st.base_r),
            effects=effects,
        )
