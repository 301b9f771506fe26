"""Interfaces for SixAxisTrack-v0 that reinforcement-learning users expect.

* :class:`ToolDisplacementAction`, the operational-space interface (``gym.make("SixAxisTrack-v0",
  interface="tool")``): the policy commands a bounded displacement of the tool point per step, in
  mm, as robosuite's ``OSC_POSITION`` and ManiSkill's ``pd_ee_delta_pos`` controllers take it, and
  observes relative quantities in mm. The displacement is mapped to joint velocities through the
  nominal model's damped pseudo-inverse, within the servo's velocity and rate limits.
* :class:`NominalToolObservation` appends what a goal-reaching task usually hands its agent: where
  the tool point is (as the *nominal* model computes it from the encoders: the agent's own belief,
  never the plant's truth) and the reference relative to it::

    env = NominalToolObservation(gym.make("SixAxisTrack-v0", scenario="geometric"))
    obs, info = env.reset(seed=1000)
    obs[env.obs_slices["ref_minus_tool"]]        # r - x_nom(q), m

  The appended parts (m, in the measurement frame):

  | name                  | size | what                                                        |
  |-----------------------|------|-------------------------------------------------------------|
  | `tool_nominal`        | 3    | x_nom(q): the nominal model's tool point at the encoders    |
  | `ref_minus_tool`      | 3    | r - x_nom(q)                                                |
  | `preview_minus_tool`  | 3P   | the previewed references minus x_nom(q)                     |

The model is the nominal description's (``task.robot``, no error parameters): a controller could
compute the same thing, so neither option adds information the agent did not have, only its form.
Both evaluate it with :class:`NominalKinematics`, one pose in a few dozen numpy operations, so that
the option costs little beside the physics step (``benchmarks/wrappers.py``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np

from arm.constraints import POSITIVE, check, refuse
from arm.description import RobotDescription
from arm.effects import REFERENCE_TEMPERATURE
from arm.kinematics import Chain
from envs.errors import ActionError, EnvOptionError, EnvStateError

__all__ = [
    "INTERFACES",
    "MAX_ERROR_AGE",
    "OBSERVABLE",
    "NominalKinematics",
    "NominalToolObservation",
    "ToolDisplacement",
    "ToolDisplacementAction",
    "nominal_reach",
    "nominal_tool_point",
    "observed",
]

#: the interfaces ``gym.make("SixAxisTrack-v0", interface=...)`` offers
INTERFACES = ("joint", "tool")
#: what the tool interface may observe beyond its relative quantities (``observe=``): the joints
#: (encoder angles and velocities), the declared payload, the temperature sensor's reading; the
#: parts follow ``previous_action`` in this order, whatever the order asked for
OBSERVABLE = ("joints", "payload", "temperature")
#: the env's own observation parts each of them appends, with the fixed scale (offset, scale) a
#: learner divides them by: ``(x - offset) / scale`` is of order 1 (rad, rad/s, kg, degC)
_OBSERVED_PARTS: dict[str, tuple[tuple[str, int, float, float], ...]] = {
    "joints": (("q", 6, 0.0, 1.0), ("qd", 6, 0.0, 1.0)),
    "payload": (("payload", 1, 0.0, 1.0),),
    "temperature": (("temperature", 1, REFERENCE_TEMPERATURE, 5.0),),
}
#: s, the age of the model error observed before the first measurement (and the cap of any age)
MAX_ERROR_AGE = 1.0
MM = 1e3
#: the tool interface's step (mm): the displacement that an action of 1 commands
TOOL_STEP_MM = POSITIVE
#: mm, the bound of every relative length the tool interface observes (twice the env's workspace)
_LENGTH_BOUND_MM = 1e4


class NominalKinematics:
    """The nominal arm's tool point and its derivative by the joint angles at one pose, in the
    measurement frame (the description's base transform and its first tool point): the
    forward kinematics of :mod:`arm.kinematics` for one pose, in Python floats. For one pose a
    3x3 product of floats costs less than a numpy call (tests check it against the error model's
    prediction and against finite differences)."""

    def __init__(self, robot: RobotDescription, target: int = 0) -> None:
        m = robot.to_modified()
        chain = Chain.from_description(m)
        base = m.base_matrix
        self.R0 = tuple(float(v) for v in base[:3, :3].reshape(-1))  # row-major
        self.o0 = tuple(float(v) for v in base[:3, 3])
        self.tool = tuple(float(v) for v in m.tool_points[target])
        self.offset = tuple(float(v) for v in chain.theta_offset)
        self.d = tuple(float(v) for v in chain.d)
        rows = []
        for alpha, beta, a in zip(chain.alpha, chain.beta, chain.a, strict=True):
            ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
            rx = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
            ry = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
            f = rx @ ry  # then TransX(a): the shift f[:, 0] * a
            rows.append(
                tuple(float(v) for v in f.reshape(-1)) + tuple(float(v) for v in f[:, 0] * a)
            )
        self.rows = tuple(rows)

    def _frames(
        self, q: Any, axes: bool = True
    ) -> tuple[list[float], list[float], tuple[float, float, float]]:
        """The joint axes z_i and points o_i on them (18 floats each, joint-major; empty without
        ``axes``) and the tool point."""
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = self.R0
        ox, oy, oz = self.o0
        z: list[float] = []
        org: list[float] = []
        cos, sin = math.cos, math.sin
        for i, (f00, f01, f02, f10, f11, f12, f20, f21, f22, sx, sy, sz) in enumerate(self.rows):
            ox += r00 * sx + r01 * sy + r02 * sz
            oy += r10 * sx + r11 * sy + r12 * sz
            oz += r20 * sx + r21 * sy + r22 * sz
            # M = R F
            m00 = r00 * f00 + r01 * f10 + r02 * f20
            m01 = r00 * f01 + r01 * f11 + r02 * f21
            m02 = r00 * f02 + r01 * f12 + r02 * f22
            m10 = r10 * f00 + r11 * f10 + r12 * f20
            m11 = r10 * f01 + r11 * f11 + r12 * f21
            m12 = r10 * f02 + r11 * f12 + r12 * f22
            m20 = r20 * f00 + r21 * f10 + r22 * f20
            m21 = r20 * f01 + r21 * f11 + r22 * f21
            m22 = r20 * f02 + r21 * f12 + r22 * f22
            th = float(q[i]) + self.offset[i]
            c, s = cos(th), sin(th)
            # R = M RotZ(theta)
            r00, r01, r02 = c * m00 + s * m01, c * m01 - s * m00, m02
            r10, r11, r12 = c * m10 + s * m11, c * m11 - s * m10, m12
            r20, r21, r22 = c * m20 + s * m21, c * m21 - s * m20, m22
            if axes:
                z += (m02, m12, m22)
                org += (ox, oy, oz)
            d = self.d[i]
            ox += m02 * d
            oy += m12 * d
            oz += m22 * d
        tx, ty, tz = self.tool
        return (
            z,
            org,
            (
                ox + r00 * tx + r01 * ty + r02 * tz,
                oy + r10 * tx + r11 * ty + r12 * tz,
                oz + r20 * tx + r21 * ty + r22 * tz,
            ),
        )

    def point(self, q: np.ndarray) -> np.ndarray:
        """The tool point (3,) m at joint angles ``q`` (6,) rad."""
        return np.array(self._frames(q)[2])

    def point_floats(self, q: Any) -> tuple[float, float, float]:
        """The tool point at ``q`` as three floats (the frames' product alone, no axes kept)."""
        return self._frames(q, axes=False)[2]

    def point_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The tool point (3,) m and its derivative by q (3, 6) m/rad: column i is
        ``z_i x (x - o_i)``."""
        x, rows = self.point_jacobian_floats(q)
        return np.array(x), np.array(rows)

    def point_jacobian_floats(
        self, q: Any
    ) -> tuple[tuple[float, float, float], tuple[list[float], list[float], list[float]]]:
        """:meth:`point_jacobian` as Python floats: the point and the Jacobian's three rows."""
        z, org, (x, y, w) = self._frames(q)
        r0: list[float] = []
        r1: list[float] = []
        r2: list[float] = []
        for i in range(0, 18, 3):
            zx, zy, zz = z[i], z[i + 1], z[i + 2]
            px, py, pz = x - org[i], y - org[i + 1], w - org[i + 2]
            r0.append(zy * pz - zz * py)
            r1.append(zz * px - zx * pz)
            r2.append(zx * py - zy * px)
        return (x, y, w), (r0, r1, r2)


def nominal_reach(robot: RobotDescription, target: int = 0) -> float:
    """A bound of the distance from the base's origin to the nominal tool point at any joint
    angles, m: the sum of every link's offsets and the tool's (the triangle inequality)."""
    kin = NominalKinematics(robot, target)
    links = sum(abs(r[9]) + abs(r[10]) + abs(r[11]) for r in kin.rows)  # TransX(a) shifts
    return float(links + sum(abs(d) for d in kin.d) + math.hypot(*kin.tool))


def nominal_tool_point(robot: RobotDescription, q: np.ndarray) -> np.ndarray:
    """The nominal model's tool point (3,) m at encoder angles ``q`` (6,)."""
    return NominalKinematics(robot).point(q)


# --------------------------------------------------------------------------------------------------
def observed(observe: Any) -> tuple[str, ...]:
    """``observe`` (names of :data:`OBSERVABLE`, any order) in the interface's order; an unknown
    or repeated name is an :class:`EnvOptionError` naming it."""
    if isinstance(observe, str) or not isinstance(observe, tuple | list):
        raise EnvOptionError(
            f"observe must be a list of names from {', '.join(OBSERVABLE)}, got {observe!r}"
        )
    for name in observe:
        if name not in OBSERVABLE:
            raise EnvOptionError(
                f"observe: unknown part {name!r}; the tool interface observes {', '.join(OBSERVABLE)}"
            )
    if len(set(observe)) != len(observe):
        raise EnvOptionError(f"observe: {list(observe)} names a part twice")
    return tuple(name for name in OBSERVABLE if name in observe)


class ToolDisplacement:
    """The operational-space interface as a pure function of the env's observation and
    controller info, for one episode: :meth:`observe` each step (the policy's observation, mm),
    then :meth:`command`, the env's joint-velocity action for the policy's tool displacement. The
    gym wrapper :class:`ToolDisplacementAction` and the learned agents share it, so a policy sees
    the same numbers in training and on the leaderboard.

    The action ``a`` in [-1, 1]^3 asks the tool to move by ``a * step_mm`` mm this step. The joint
    velocity is ``v = J^T (J J^T + damping^2 I)^-1 (a * step_mm / dt)`` with J the nominal model's
    Jacobian at the encoders (the damped pseudo-inverse of the ``nominal`` controller), scaled
    down as a whole into the velocity limits, changed by at most ``a_max * dt`` per step (the
    servo's rate limit: what the plant would do to the command anyway, applied before it so the
    direction is kept as far as it can be) and stopped at a joint limit.

    The observation (``obs_slices`` names each part; ``low``/``high`` its bounds, ``feature_offset``
    and ``feature_scale`` the fixed scales a learner normalises it by, ``(x - offset) / scale``,
    which the trainer uses and saves with the policy):

    | name                | size | what                                                  | unit  | offset | scale   |
    |---------------------|------|-------------------------------------------------------|-------|--------|---------|
    | `tracking_error`    | 3    | r - (x_nom(q) + e): the reference minus the tool point | mm   | 0      | 1       |
    |                     |      | as the nominal model corrected by the last measurement |      |        |         |
    |                     |      | places it                                              |      |        |         |
    | `preview`           | 3P   | the next P references minus the reference now         | mm    | 0      | step_mm |
    | `model_error`       | 3    | e = y - x_nom(q_y) at the last tracker measurement y  | mm    | 0      | 1       |
    |                     |      | (0 before one)                                        |       |        |         |
    | `model_error_age`   | 1    | its age, capped at 1 (1 before the first measurement) | s     | 0      | 0.1     |
    | `previous_action`   | 3    | the last action, in [-1, 1]                           | 1     | 0      | 1       |

    With ``observe`` (any of :data:`OBSERVABLE`), the env's own readings follow, in its units
    (``obs_slices`` names them as the env does; bounds: the env's):

    | observe         | name          | size | what                                    | unit  | offset | scale |
    |-----------------|---------------|------|-----------------------------------------|-------|--------|-------|
    | `"joints"`      | `q`           | 6    | encoder angles (motor side)             | rad   | 0      | 1     |
    |                 | `qd`          | 6    | encoder velocities                      | rad/s | 0      | 1     |
    | `"payload"`     | `payload`     | 1    | the payload as the operator declared it | kg    | 0      | 1     |
    | `"temperature"` | `temperature` | 1    | the arm's temperature sensor's reading  | degC  | 20     | 5     |

    Without them the policy cannot tell the configuration-, load- and temperature-dependent
    errors the scenarios hide from one another: only the tracker's model error, as it was at the
    last measurement.

    The true tool point is about ``x_nom(q) + e`` (what ``feedforward`` tracks with), so the
    tracking error is the best estimate of the true one the agent has, and ``a = (p_1 + gain * t)
    / step_mm`` (``t`` the tracking error, ``p_1`` the first preview point) is the ``feedforward``
    controller: a linear policy of these features tracks as well as it does. (With ``r - x_nom(q)``
    instead, a policy must weigh the tracking error and the model error exactly alike to reach
    the same point; trained policies missed by 10-15 % of the model error, 0.3-0.5 mm.)
    """

    def __init__(
        self,
        task: Any,
        step_mm: float = 5.0,
        damping: float = 1e-3,
        observe: tuple[str, ...] | list[str] = (),
    ) -> None:
        refuse(
            check({"tool_step_mm": step_mm}, {"tool_step_mm": ([TOOL_STEP_MM], False)}),
            EnvOptionError,
        )
        self.observe_parts = observed(observe)
        self.task = task
        self.step_mm = float(step_mm)
        self.damping = float(damping)
        self.kin = NominalKinematics(task.robot)
        self.P = int(task.preview_steps)
        sl = task.obs_slices
        self._q, self._ref, self._preview = sl["q"], sl["ref"], sl["preview"]
        self._meas_age = sl["meas_age"].start
        self.dt = float(task.dt)
        self.v_max = np.asarray(task.v_max, dtype=float)
        self.dv = np.asarray(task.a_max, dtype=float) * self.dt
        self.q_lower = np.asarray(task.q_lower, dtype=float)
        self.q_upper = np.asarray(task.q_upper, dtype=float)
        self._v_max = self.v_max.tolist()
        self._dv = self.dv.tolist()
        self._lower, self._upper = self.q_lower.tolist(), self.q_upper.tolist()
        extra = [part for name in self.observe_parts for part in _OBSERVED_PARTS[name]]
        sizes = (
            ("tracking_error", 3),
            ("preview", 3 * self.P),
            ("model_error", 3),
            ("model_error_age", 1),
            ("previous_action", 3),
            *((name, n) for name, n, _, _ in extra),
        )
        self.obs_slices: dict[str, slice] = {}
        k = 0
        for name, n in sizes:
            self.obs_slices[name] = slice(k, k + n)
            k += n
        self.obs_size = k
        self._age = self.obs_slices["model_error_age"].start
        self._action_end = self.obs_slices["previous_action"].stop
        #: (where in this observation, where in the env's) of each of the env's parts observed
        self._copied = [(self.obs_slices[name], sl[name]) for name, _, _, _ in extra]
        # the env's parts are bounded by the env's own space (ToolDisplacementAction's), here not
        high = np.full(k, np.inf)
        high[: self._action_end] = _LENGTH_BOUND_MM
        high[self.obs_slices["model_error_age"]] = MAX_ERROR_AGE
        high[self.obs_slices["previous_action"]] = 1.0
        low = -high
        low[self.obs_slices["model_error_age"]] = 0.0
        self.low, self.high = low, high
        #: a typical size of each feature (mm, s, 1, rad, rad/s, kg, K) and its centre: a
        #: learner's fixed normalisation, ``(x - feature_offset) / feature_scale``
        scale, offset = np.ones(k), np.zeros(k)
        scale[self.obs_slices["preview"]] = self.step_mm
        scale[self.obs_slices["model_error_age"]] = 0.1
        for name, _, centre, size in extra:
            offset[self.obs_slices[name]], scale[self.obs_slices[name]] = centre, size
        self.feature_scale, self.feature_offset = scale, offset
        self.reset()

    def reset(self) -> None:
        """Start an episode (or a phase): no measurement yet, the arm at rest."""
        self.error = np.zeros(3)
        self.error_time = -math.inf
        self.prev_action = np.zeros(3)
        self.v_prev = np.zeros(6)
        self._pose: tuple[list[float], tuple[list[float], list[float], list[float]]] | None = None

    def observe(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        """The policy's observation (float64, mm) for the env's ``obs`` and the controllers'
        part of ``info`` (the tracker's measurement, when one arrived, updates the model error)."""
        obs = np.asarray(obs, dtype=float)
        q = obs[self._q].tolist()
        x, J = self.kin.point_jacobian_floats(q)
        self._pose = (q, J)
        if info.get("measurement_valid", False):
            self._measured(info, q, x)
        t = info.get("time")
        if not math.isfinite(self.error_time):
            age = MAX_ERROR_AGE
        elif t is None:  # no clock: the tracker's own age of its last sample
            age = float(obs[self._meas_age])
        else:
            age = float(t) - self.error_time
        ref = obs[self._ref]
        out = np.empty(self.obs_size)
        sl = self.obs_slices
        out[sl["tracking_error"]] = ref - x - self.error
        out[sl["preview"]] = (obs[self._preview].reshape(-1, 3) - ref).reshape(-1)
        out[sl["model_error"]] = self.error
        out[: self._age] *= MM
        out[self._age] = min(max(age, 0.0), MAX_ERROR_AGE)
        out[self._age + 1 : self._action_end] = self.prev_action
        for mine, env_part in self._copied:
            out[mine] = obs[env_part]
        return out

    def _measured(self, info: Mapping[str, Any], q: list[float], x: Any) -> None:
        y = np.asarray(info.get("measurement"), dtype=float).reshape(-1)
        given = info.get("measurement_q")
        q_y = np.asarray(q if given is None else given, dtype=float).reshape(-1)
        if y.shape != (3,) or q_y.shape != (6,) or not np.isfinite(y).all():
            return
        if not np.isfinite(q_y).all():
            return
        self.error = y - (np.array(x) if given is None else self.kin.point(q_y))
        t = info.get("measurement_time", info.get("time"))
        self.error_time = float(t) if t is not None else math.nan

    def clipped(self, features: np.ndarray) -> np.ndarray:
        """The observation within its bounds (``low``, ``high``: the wrapper's space), in place."""
        np.minimum(features, self.high, out=features)
        return np.maximum(features, self.low, out=features)

    def joint_velocity(self, action: np.ndarray) -> np.ndarray:
        """The joint velocity (6,) rad/s the action asks for (limits applied); remembers it."""
        if self._pose is None:
            raise EnvStateError("ToolDisplacement.command before observe(): no pose yet")
        a = np.array(action, dtype=float).reshape(-1)
        if a.shape != (3,) or not math.isfinite(a.sum()):
            raise ActionError(
                f"the tool interface's action must be 3 finite numbers, got {action!r}"
            )
        np.minimum(a, 1.0, out=a)
        np.maximum(a, -1.0, out=a)
        q, (j0, j1, j2) = self._pose
        # v = J^T (J J^T + damping^2 I)^-1 xd, the 3x3 system solved by Cramer's rule, in floats
        lam2 = self.damping**2
        a00 = sum(u * u for u in j0) + lam2
        a11 = sum(u * u for u in j1) + lam2
        a22 = sum(u * u for u in j2) + lam2
        a01 = sum(u * w for u, w in zip(j0, j1, strict=True))
        a02 = sum(u * w for u, w in zip(j0, j2, strict=True))
        a12 = sum(u * w for u, w in zip(j1, j2, strict=True))
        c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
        c11, c12, c22 = a00 * a22 - a02 * a02, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01
        k = self.step_mm / MM / self.dt / (a00 * c00 + a01 * c01 + a02 * c02)
        b0, b1, b2 = a.tolist()
        b0, b1, b2 = b0 * k, b1 * k, b2 * k
        w0 = c00 * b0 + c01 * b1 + c02 * b2
        w1 = c01 * b0 + c11 * b1 + c12 * b2
        w2 = c02 * b0 + c12 * b1 + c22 * b2
        v = [w0 * u0 + w1 * u1 + w2 * u2 for u0, u1, u2 in zip(j0, j1, j2, strict=True)]
        scale = max(abs(vi) / vm for vi, vm in zip(v, self._v_max, strict=True))
        if scale > 1.0:
            v = [vi / scale for vi in v]
        out = []
        dt = self.dt
        for vi, vp, dv, qi, lo, hi in zip(
            v, self.v_prev.tolist(), self._dv, q, self._lower, self._upper, strict=True
        ):
            vi = vp + min(max(vi - vp, -dv), dv)  # the servo's rate limit
            qn = qi + dt * vi
            if (qn < lo and vi < 0) or (qn > hi and vi > 0):  # not into a joint limit
                vi = 0.0
            out.append(vi)
        self.prev_action = a
        self.v_prev = np.array(out)
        return self.v_prev

    def command(self, action: np.ndarray) -> np.ndarray:
        """The env's action (6,): normalised joint velocities for the tool displacement (within
        [-1, 1]: the velocity limits are applied)."""
        return self.joint_velocity(action) / self.v_max


class ToolDisplacementAction(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """SixAxisTrack-v0 with the operational-space interface of :class:`ToolDisplacement`: the
    action ``Box(-1, 1, (3,))`` is a tool displacement of up to ``step_mm`` mm per step and axis,
    the observation ``Box(low, high, (10 + 3P,), float32)`` the relative quantities in mm that
    :class:`ToolDisplacement` lists (``obs_slices`` names them), followed by the env's own
    readings ``observe`` asks for (:data:`OBSERVABLE`, within the env's bounds). The observation
    is not normalised: ``feature_offset`` and ``feature_scale`` are the fixed scales a learner
    divides it by (``(obs - offset) / scale``, the trainer's). Reward, episode end and ``info``
    are the env's (its jerk penalty is on the joint-velocity command the interface sends)."""

    def __init__(
        self,
        env: gym.Env,
        step_mm: float = 5.0,
        damping: float = 1e-3,
        observe: tuple[str, ...] | list[str] = (),
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, step_mm=step_mm, damping=damping, observe=tuple(observe)
        )
        super().__init__(env)
        task = env.unwrapped.task  # type: ignore[attr-defined]
        self.interface = ToolDisplacement(task, step_mm, damping, observe)
        self.obs_slices = dict(self.interface.obs_slices)
        self.feature_offset = self.interface.feature_offset.copy()
        self.feature_scale = self.interface.feature_scale.copy()
        low, high = self.interface.low.copy(), self.interface.high.copy()
        base = env.observation_space
        assert isinstance(base, gym.spaces.Box)
        for name in self.interface.obs_slices:
            if name in task.obs_slices and not np.isfinite(high[self.obs_slices[name]]).all():
                low[self.obs_slices[name]] = base.low[task.obs_slices[name]]
                high[self.obs_slices[name]] = base.high[task.obs_slices[name]]
        self.observation_space = gym.spaces.Box(
            low.astype(np.float32), high.astype(np.float32), (self.interface.obs_size,), np.float32
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.interface.reset()
        return self._obs(obs, info), info

    def step(self, action: Any):
        obs, reward, terminated, truncated, info = self.env.step(self.interface.command(action))
        return self._obs(obs, info), reward, terminated, truncated, info

    def _obs(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        return self.interface.clipped(self.interface.observe(obs, info)).astype(np.float32)


class NominalToolObservation(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """SixAxisTrack-v0's observation followed by ``tool_nominal``, ``ref_minus_tool`` and
    ``preview_minus_tool`` (see the module docstring); ``obs_slices`` names every part. Its bounds
    are finite: the nominal tool point lies within the arm's reach (:func:`nominal_reach` from
    the base), the references within the env's bounds, and their differences within the sum."""

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        super().__init__(env)
        task = env.unwrapped.task  # type: ignore[attr-defined]
        self.task = task
        self.kin = NominalKinematics(task.robot)
        n0 = int(task.obs_size)
        P = int(task.preview_steps)
        slices = dict(task.obs_slices)
        k = n0
        for name, n in (("tool_nominal", 3), ("ref_minus_tool", 3), ("preview_minus_tool", 3 * P)):
            slices[name] = slice(k, k + n)
            k += n
        self.obs_slices = slices
        self._n0 = n0
        self._q, self._ref, self._preview = (
            task.obs_slices["q"],
            task.obs_slices["ref"],
            task.obs_slices["preview"],
        )
        base = env.observation_space
        assert isinstance(base, gym.spaces.Box)
        # the tool point within the reach of the base's origin; the references within the env's
        # bounds: each difference within their sum (float32-safe: rounded outwards by a mm)
        o0 = np.asarray(self.kin.o0)
        tool_lo, tool_hi = (
            o0 - nominal_reach(task.robot) - 1e-3,
            o0 + nominal_reach(task.robot) + 1e-3,
        )
        ref_lo = np.minimum(base.low[self._ref], base.low[self._preview].reshape(-1, 3).min(0))
        ref_hi = np.maximum(base.high[self._ref], base.high[self._preview].reshape(-1, 3).max(0))
        diff_lo, diff_hi = ref_lo - tool_hi, ref_hi - tool_lo
        low = np.concatenate([base.low, tool_lo, np.tile(diff_lo, 1 + P)]).astype(np.float32)
        high = np.concatenate([base.high, tool_hi, np.tile(diff_hi, 1 + P)]).astype(np.float32)
        self.observation_space = gym.spaces.Box(low, high, (k,), np.float32)
        # the reference and its preview are one block of the env's observation: one subtraction
        self._points = slice(self._ref.start, self._preview.stop)
        if self._ref.stop != self._preview.start:
            raise EnvOptionError(
                "NominalToolObservation needs the preview right after the reference"
            )

    def observation(self, observation: Any) -> np.ndarray:
        obs = np.asarray(observation, dtype=float)
        x = np.array(self.kin.point_floats(obs[self._q].tolist()))
        n0 = self._n0
        out = np.empty(n0 + 3 + (self._points.stop - self._points.start), dtype=np.float32)
        out[:n0] = observation
        out[n0 : n0 + 3] = x
        np.subtract(obs[self._points].reshape(-1, 3), x, out=out[n0 + 3 :].reshape(-1, 3))
        return out
