"""The pose-error model: a robot description plus a list of effects, predicting the measured tool
point of every pose and the identification Jacobian (derivatives by every named parameter).

    model = ErrorModel(seed_robot(), "geometric,compliance")
    inputs = model.inputs(q, columns)          # per data set: gravity torques, directions, ...
    p = model.nominal()                        # a vector laid out by model.layout
    xyz, J = model.predict(inputs, p, jacobian=True)   # (N, 3), (N, 3, P)

Prediction: joint-angle effects change theta at the encoder reading q; chain effects change the
DH table (geometric errors first, then thermal scaling); the tool point of each pose's target goes
through the frames and the base transform into the measurement frame.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from envs.description import RobotDescription
from envs.effects import (
    ChainEffect,
    Effect,
    EffectError,
    JointAngleEffect,
    _skew,
    parse_effects,
    so3_left_jacobian,
)
from envs.kinematics import Chain, gravity_torques, link_frames
from envs.params import ParameterLayout

__all__ = ["ChainState", "ErrorModel", "ModelInputs", "Sensitivities"]

log = logging.getLogger(__name__)


@dataclass
class ModelInputs:
    """Everything per pose that the model needs besides the parameters, computed once per data set.

    ``tau`` are the gravity torques of the nominal arm at the encoder reading (payload included);
    ``target`` is each pose's index into the model's targets.
    """

    robot: RobotDescription
    targets: tuple[int, ...]
    q: np.ndarray
    tau: np.ndarray
    target: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    _cache: dict = field(default_factory=dict, repr=False)

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

    def subset(self, idx: np.ndarray) -> ModelInputs:
        """The inputs of some poses only (for cross-validation and held-out tests)."""
        return ModelInputs(
            robot=self.robot,
            targets=self.targets,
            q=self.q[idx],
            tau=self.tau[idx],
            target=self.target[idx],
            columns={k: v[idx] for k, v in self.columns.items()},
        )


@dataclass(frozen=True)
class ChainState:
    """The chain as the effects leave it: DH arrays, base transform, tool points per target."""

    robot: RobotDescription
    targets: tuple[int, ...]
    chain: Chain
    base_R: np.ndarray
    base_t: np.ndarray
    base_r: np.ndarray
    tools: np.ndarray  # (n_targets, 3), in the last frame
    length_scale: np.ndarray | None = None  # (N,) product of length scalings (thermal)

    def replace(self, **kw) -> ChainState:
        return replace(self, **kw)


@dataclass(frozen=True)
class Sensitivities:
    """Elementary derivatives of the measured point (N, 3, ...) in the measurement frame.

    ``d_alpha[:, :, i]`` is d p / d alpha of row i+1 (likewise a, beta, theta, d, all at the state's
    values), ``d_base`` by (bx, by, bz, brx, bry, brz), ``d_tool`` by the tool point of the pose's
    target (the target's columns are masked by the effect).
    """

    state: ChainState
    d_alpha: np.ndarray
    d_beta: np.ndarray
    d_a: np.ndarray
    d_theta: np.ndarray
    d_d: np.ndarray
    d_base: np.ndarray
    d_tool: np.ndarray


class ErrorModel:
    """A robot description with a list of effects; see the module docstring."""

    def __init__(
        self,
        robot: RobotDescription,
        effects: str | Sequence[str | Effect] = "geometric",
        targets: Sequence[int] = (0,),
    ) -> None:
        self.robot = robot.to_modified()
        self.effects: list[Effect] = parse_effects(effects)
        self.targets = tuple(int(t) for t in targets)
        if not self.targets or len(set(self.targets)) != len(self.targets):
            raise ValueError(f"targets must be distinct ids, got {targets}")
        self.layout = ParameterLayout.of(
            (e.name, e.parameter_names(self.robot, self.targets)) for e in self.effects
        )
        self._chain0 = Chain.from_description(self.robot)
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

    def __repr__(self) -> str:
        return f"ErrorModel({self.robot.name!r}, {[e.label for e in self.effects]}, {len(self.layout)} parameters)"

    @property
    def effect_names(self) -> list[str]:
        return [e.label for e in self.effects]

    def with_effects(self, effects: str | Sequence[str | Effect]) -> ErrorModel:
        return ErrorModel(self.robot, effects, self.targets)

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
            raise ValueError(f"{source}: joint angles must have shape (N, 6), got {q.shape}")
        cols = {k: np.asarray(v, dtype=float) for k, v in (columns or {}).items()}
        missing = sorted(c for c in self.required_columns() if c not in cols)
        if missing:
            needs = {c: [e.name for e in self.effects if c in e.columns] for c in missing}
            detail = "; ".join(f"{c} (needed by {', '.join(v)})" for c, v in needs.items())
            raise EffectError(f"{source}: missing column(s) {detail}")
        payload = cols.get("payload")
        tau = gravity_torques(self.robot, q, payload=payload)
        if "target" in cols:
            t = cols["target"]
            if np.any(t != np.round(t)):
                raise EffectError(f"{source}: target ids must be integers")
            ids = np.array(self.targets)
            order = np.argsort(ids)
            pos = np.clip(np.searchsorted(ids[order], t), 0, len(ids) - 1)
            found = ids[order][pos] == t
            if not found.all():
                unknown = sorted({int(v) for v in t[~found]})
                raise EffectError(
                    f"{source}: target id(s) {unknown} not among the model's {self.targets}"
                )
            target = order[pos]
        else:
            if len(self.targets) > 1:
                raise EffectError(
                    f"{source}: the model has several targets but the data no 'target' column"
                )
            target = np.zeros(q.shape[0], dtype=int)
        return ModelInputs(self.robot, self.targets, q, tau, target, cols)

    # -- evaluation ---------------------------------------------------------------------------
    def _values(self, p: np.ndarray, effect: Effect) -> np.ndarray:
        return p[self.layout.slice(effect.name)]

    def joint_angles(self, inputs: ModelInputs, p: np.ndarray) -> np.ndarray:
        """The effective joint angles (N, 6): encoder reading plus every joint-angle effect."""
        theta = inputs.q.copy()
        for e in self._joint_effects:
            theta += e.joint_offsets(inputs, self._values(p, e))
        return theta

    def state(self, inputs: ModelInputs | None, p: np.ndarray) -> ChainState:
        """The chain after every chain effect (``inputs`` may be None without per-pose effects)."""
        st = self._initial_state()
        for e in self._chain_effects:
            st = e.apply(inputs, self._values(p, e), st)
        return st

    def _initial_state(self) -> ChainState:
        return ChainState(
            robot=self.robot,
            targets=self.targets,
            chain=self._chain0,
            base_R=self.robot.base_matrix[:3, :3],
            base_t=np.array(self.robot.base_translation, dtype=float),
            base_r=np.array(self.robot.base_rotation, dtype=float),
            tools=self._tools0.copy(),
        )

    def predict(
        self, inputs: ModelInputs, p: np.ndarray, jacobian: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Measured points (N, 3); with ``jacobian=True`` also d points / d p (N, 3, P)."""
        p = np.asarray(p, dtype=float)
        if p.shape != (len(self.layout),):
            raise ValueError(f"expected {len(self.layout)} parameters, got shape {p.shape}")
        theta = self.joint_angles(inputs, p)
        st = self.state(inputs, p)
        f = link_frames(st.chain, theta)
        tool = st.tools[inputs.target]
        pb = f.o[:, 6] + np.einsum("nij,nj->ni", f.R[:, 6], tool)
        xyz = pb @ st.base_R.T + st.base_t
        if not jacobian:
            return xyz
        sens = self._sensitivities(f, pb, st)
        J = np.empty((inputs.n, 3, len(self.layout)))
        for e in self.effects:
            sl = self.layout.slice(e.name)
            v = p[sl]
            if isinstance(e, JointAngleEffect):
                J[:, :, sl] = np.einsum("nxj,njk->nxk", sens.d_theta, e.joint_jacobian(inputs, v))
            else:
                cols = e.jacobian(inputs, v, sens)
                J[:, :, sl] = self._numeric_columns(inputs, p, sl) if cols is None else cols
        return xyz, J

    def joint_jacobian(self, inputs: ModelInputs, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measured points (N, 3) and their derivatives by the effective joint angles theta
        (N, 3, 6), in the measurement frame: the step direction of inverse kinematics on the
        calibrated model (:func:`envs.ik.solve_position`)."""
        p = np.asarray(p, dtype=float)
        theta = self.joint_angles(inputs, p)
        st = self.state(inputs, p)
        f = link_frames(st.chain, theta)
        pb = f.o[:, 6] + np.einsum("nij,nj->ni", f.R[:, 6], st.tools[inputs.target])
        Rb = st.base_R
        J = np.cross(f.z, pb[:, None, :] - f.o[:, 1:]) @ Rb.T  # (N, 6, 3)
        return pb @ Rb.T + st.base_t, J.transpose(0, 2, 1)

    def _sensitivities(self, f, pb: np.ndarray, st: ChainState) -> Sensitivities:
        Rb = st.base_R
        z = f.z
        r_prev = pb[:, None, :] - f.o[:, :6]
        r_this = pb[:, None, :] - f.o[:, 1:]

        def to_meas(v):  # (N, 6, 3) base-frame vectors -> (N, 3, 6) measurement frame
            return np.einsum("ij,nkj->nik", Rb, v)

        d_base = np.empty((pb.shape[0], 3, 6))
        d_base[:, :, :3] = np.eye(3)
        d_base[:, :, 3:] = -_skew(pb @ Rb.T) @ so3_left_jacobian(st.base_r)
        return Sensitivities(
            state=st,
            d_alpha=to_meas(np.cross(f.x_alpha, r_prev)),
            d_beta=to_meas(np.cross(f.y_beta, r_prev)),
            d_a=to_meas(f.x_a),
            d_theta=to_meas(np.cross(z, r_this)),
            d_d=to_meas(z),
            d_base=d_base,
            d_tool=np.einsum("ij,njk->nik", Rb, f.R[:, 6]),
        )

    def _numeric_columns(self, inputs: ModelInputs, p: np.ndarray, sl: slice) -> np.ndarray:
        """Central differences for an effect without analytic columns."""
        cols = []
        for k in range(sl.start, sl.stop):
            h = 1e-6 * max(1.0, abs(p[k]))
            pp, pm = p.copy(), p.copy()
            pp[k] += h
            pm[k] -= h
            cols.append((self.predict(inputs, pp) - self.predict(inputs, pm)) / (2 * h))
        return np.stack(cols, axis=-1) if cols else np.empty((inputs.n, 3, 0))

    # -- a calibrated arm as a description -----------------------------------------------------
    def description(self, p: np.ndarray, name: str | None = None) -> RobotDescription:
        """The arm with the parameters ``p`` folded in: a description that reproduces this model's
        predictions with zero errors (non-geometric effect values go to ``effects``)."""
        st = self._initial_state()
        for e in self._chain_effects:  # per-pose effects (thermal) stay effects, not geometry
            if not e.columns:
                st = e.apply(None, self._values(p, e), st)
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
            tools=tuple(tuple(float(c) for c in t) for t in st.tools),
            base_translation=tuple(float(c) for c in st.base_t),
            base_rotation=tuple(float(c) for c in st.base_r),
            effects=effects,
        )
