"""The error model's measured tool point as a CasADi expression, for controllers and estimators.

:class:`arm.errormodel.ErrorModel` is the project's model (numpy, batched over poses). A controller
needs the same prediction for one pose at every control step, its derivative by the joint angles
(to linearise the kinematics for the MPC's QP), its derivative by the parameters (for recursive
least squares) and, for the nonlinear MPC, the expression itself inside an optimisation problem.
:class:`ToolModel` builds that expression once from the model's description and effects:

    tm = ToolModel(ErrorModel(seed_robot(), "geometric,compliance"))
    x, Jq, Jp = tm.evaluate(q, p, {"payload": 0.0})   # (3,), (3, 6), (3, P): one compiled call
    expr = tm.expression(q_sym, p_sym, c_sym)          # for an NLP

It is a second, independent implementation of the error model (CasADi's algorithmic derivatives
instead of the analytic Jacobian); the tests check it against :meth:`ErrorModel.predict`.

Every catalogued effect is translated. A model with a user's joint-angle effect still works: that
effect's joint offsets are computed by its numpy ``basis`` at each call and enter as an input
(their derivative by q is neglected, like the other effects' second-order terms); a user's chain
effect is refused with a clear error.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass

import casadi as ca
import numpy as np

from agents.errors import UnsupportedEffectError
from arm.effects import (
    REFERENCE_TEMPERATURE,
    Backlash,
    ChainEffect,
    Compliance,
    Cyclic,
    Geometric,
    JointAngleEffect,
    JointScale,
    LoadBacklash,
    Thermal,
    Transmission,
)
from arm.errormodel import ErrorModel
from arm.errors import ModelError
from arm.kinematics import Chain

__all__ = [
    "BufferedFunction",
    "ToolEval",
    "ToolModel",
    "UnsupportedEffectError",
    "cached_tool_model",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ToolEval:
    """One pose's prediction: the point (3,) and its derivatives by q (3, 6) and by p (3, P)."""

    x: np.ndarray
    Jq: np.ndarray
    Jp: np.ndarray


_NO_OFFSET = np.zeros(6)
_NO_OFFSET.flags.writeable = False


class BufferedFunction:
    """A CasADi function of one vector input and one vector output, called through buffers of
    its own (``Function.buffer``): the argument and the result are numpy arrays that CasADi reads
    and writes in place. A plain call converts numpy to CasADi's matrices and back, which costs
    30-40 us whatever the size (more than evaluating the tool point and its Jacobian); this costs
    about 1 us plus the evaluation.

    ``f(x)`` returns the result array itself, overwritten by the next call: copy what you keep.
    One instance is not to be called from two threads at once.
    """

    def __init__(self, f: ca.Function) -> None:
        if f.n_in() != 1 or f.n_out() != 1:
            raise UnsupportedEffectError(f"{f.name()}: expected one input and one output")
        if not (f.sparsity_in(0).is_dense() and f.sparsity_out(0).is_dense()):
            raise UnsupportedEffectError(f"{f.name()}: input and output must be dense (ca.densify)")
        self.function = f
        self.arg = np.zeros(f.nnz_in(0))
        self.res = np.zeros(f.nnz_out(0))
        self._buf, self._eval = f.buffer()
        # (CasADi's stubs ask for a size; the binding takes the buffer's own)
        self._buf.set_arg(0, memoryview(self.arg))  # type: ignore[call-arg, arg-type]
        self._buf.set_res(0, memoryview(self.res))  # type: ignore[call-arg, arg-type]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        self.arg[:] = x
        self._eval()
        return self.res

    def evaluate(self) -> np.ndarray:
        """Evaluate on what :attr:`arg` holds now (written in place by the caller)."""
        self._eval()
        return self.res

    # buffers hold raw pointers into this instance's arrays: copies get their own
    def __copy__(self) -> BufferedFunction:
        return BufferedFunction(self.function)

    def __deepcopy__(self, memo) -> BufferedFunction:
        return BufferedFunction(self.function)

    def __getstate__(self):
        return {"function": self.function}

    def __setstate__(self, state) -> None:
        BufferedFunction.__init__(self, state["function"])


def _rot_x(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))


def _rot_y(b):
    c, s = ca.cos(b), ca.sin(b)
    return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))


def _rot_z(t):
    c, s = ca.cos(t), ca.sin(t)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def _skew(v):
    return ca.vertcat(
        ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]), ca.horzcat(-v[1], v[0], 0)
    )


def rodrigues(r: ca.SX) -> ca.SX:
    """Rotation matrix of a rotation vector, smooth (with derivatives) at r = 0."""
    th2 = ca.dot(r, r)
    small = th2 < 1e-8
    safe = ca.if_else(small, 1.0, th2)  # keeps the unused branch finite at 0
    th = ca.sqrt(safe)
    a = ca.if_else(small, 1 - th2 / 6 + th2**2 / 120, ca.sin(th) / th)
    b = ca.if_else(small, 0.5 - th2 / 24 + th2**2 / 720, (1 - ca.cos(th)) / safe)
    K = _skew(r)
    return ca.SX.eye(3) + a * K + b * (K @ K)


def _frames(alpha, beta, a, d, theta):
    """Rotations and origins of frames 1..6 of a modified-DH chain (lists of SX)."""
    R = ca.SX.eye(3)
    o = ca.SX.zeros(3)
    Rs, os_ = [], []
    for i in range(6):
        Q = R @ _rot_x(alpha[i]) @ _rot_y(beta[i])
        o = o + a[i] * Q[:, 0] + d[i] * Q[:, 2]
        R = Q @ _rot_z(theta[i])
        Rs.append(R)
        os_.append(o)
    return Rs, os_


class ToolModel:
    """See the module docstring. ``target`` is the index of the measured tool point."""

    def __init__(self, model: ErrorModel, target: int = 0) -> None:
        self.model = model
        self.layout = model.layout
        self.target = int(target)
        robot = model.robot
        if robot.couplings:
            raise UnsupportedEffectError(
                f"robot {robot.name!r} has coupled joints: the MPC's CasADi model turns each "
                "joint on its own and does not represent them"
            )
        if robot.extra_joints:
            raise UnsupportedEffectError(
                f"robot {robot.name!r} stands on extra joints: the MPC's CasADi model places "
                "the arm's base once and does not represent them"
            )
        self._chain0 = Chain.from_description(robot)
        self._tool0 = np.array(robot.tool_points[min(self.target, len(robot.tools) - 1)])
        self._custom: list[JointAngleEffect] = []
        for e in model.effects:
            if isinstance(e, ChainEffect) and type(e) not in (Geometric, Thermal):
                raise UnsupportedEffectError(
                    f"chain effect {e.name!r} has no CasADi form; the MPC supports "
                    "geometric and thermal chain effects and any joint-angle effect"
                )
            if isinstance(e, JointAngleEffect) and type(e) not in _BASIS:
                self._custom.append(e)
        cols = {"payload"}
        for e in model.effects:
            cols |= set(e.columns)
        self.column_names: tuple[str, ...] = tuple(sorted(cols))
        self._defaults = {
            "payload": float(robot.payload),
            "temperature": REFERENCE_TEMPERATURE,
        }
        P = len(self.layout)
        q = ca.SX.sym("q", 6)
        p = ca.SX.sym("p", P)
        c = ca.SX.sym("c", len(self.column_names))
        extra = ca.SX.sym("offset", 6)  # joint offsets of user effects, computed in numpy
        x = self.expression(q, p, c, extra)
        # one packed input and one packed output per function: every numpy <-> CasADi conversion
        # costs tens of microseconds, whatever its size
        z = ca.vertcat(q, p, c, extra)
        self.n_inputs = z.shape[0]
        self._f_q = ca.Function(
            "tool_point_dq", [z], [ca.densify(ca.vertcat(x, ca.vec(ca.jacobian(x, q))))]
        )
        self._f_p = ca.Function(
            "tool_point_dp", [z], [ca.densify(ca.vertcat(x, ca.vec(ca.jacobian(x, p))))]
        )
        self._f_point = ca.Function("tool_point", [z], [x])
        self._b_q = BufferedFunction(self._f_q)
        self._b_p = BufferedFunction(self._f_p)

    def __repr__(self) -> str:
        return f"ToolModel({self.model!r})"

    # -- inputs ---------------------------------------------------------------------------------
    def column_vector(self, columns: Mapping[str, float] | None = None) -> np.ndarray:
        """The model's per-pose columns in this model's order; missing ones take defaults
        (temperature 20 degC, the description's payload, direction 0 = unknown)."""
        columns = columns or {}
        out = []
        for name in self.column_names:
            v = columns.get(name)
            v = float(v) if v is not None else math.nan
            out.append(v if math.isfinite(v) else self._defaults.get(name, 0.0))
        return np.array(out)

    def _offsets(self, q: np.ndarray, p: np.ndarray, cvec: np.ndarray) -> np.ndarray:
        if not self._custom:
            return _NO_OFFSET
        inputs = self.model.inputs(
            q[None, :], dict(zip(self.column_names, cvec[:, None], strict=True))
        )
        out = np.zeros(6)
        for e in self._custom:
            out += e.joint_offsets(inputs, p[self.layout.slice(e.name)])[0]
        return out

    # -- evaluation -----------------------------------------------------------------------------
    def pack(self, q, p, columns) -> np.ndarray:
        """The packed input [q, p, columns, user-effect offsets] of the compiled functions."""
        q = np.asarray(q, dtype=float).reshape(6)
        p = np.asarray(p, dtype=float).reshape(-1)
        if p.shape != (len(self.layout),):
            raise ModelError(f"expected {len(self.layout)} parameters, got shape {p.shape}")
        cvec = columns if isinstance(columns, np.ndarray) else self.column_vector(columns)
        return np.concatenate([q, p, cvec, self._offsets(q, p, cvec)])

    def evaluate(
        self, q: np.ndarray, p: np.ndarray, columns: Mapping[str, float] | np.ndarray | None = None
    ) -> ToolEval:
        """Point, d point / d q and d point / d p at one pose (``columns`` a mapping or a vector
        from :meth:`column_vector`)."""
        z = self.pack(q, p, columns)
        x, Jq = self._split(self._b_q(z), 6)
        _, Jp = self._split(self._b_p(z), len(self.layout))
        return ToolEval(x, Jq, Jp)

    @staticmethod
    def _split(v: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        return v[:3].copy(), v[3:].reshape(n, 3).T.copy()

    def point_dq(
        self, q: np.ndarray, p: np.ndarray, columns: Mapping[str, float] | np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The point (3,) and its derivative by the joint angles (3, 6): the MPC's linearisation."""
        return self._split(self._b_q(self.pack(q, p, columns)), 6)

    def point_dp(
        self, q: np.ndarray, p: np.ndarray, columns: Mapping[str, float] | np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The point (3,) and its derivative by the parameters (3, P): the estimator's regressor."""
        return self._split(self._b_p(self.pack(q, p, columns)), len(self.layout))

    def point(
        self, q: np.ndarray, p: np.ndarray, columns: Mapping[str, float] | np.ndarray | None = None
    ) -> np.ndarray:
        return self._f_point(self.pack(q, p, columns)).full().reshape(3)

    # -- the expression -------------------------------------------------------------------------
    def expression(self, q, p, c, offset=None):
        """The measured tool point (3x1) as an expression of q (6), p (P), columns c and an
        optional joint offset (6) of user effects. Works for SX and MX symbols."""
        if isinstance(q, ca.MX) or isinstance(p, ca.MX):
            # build in SX once, then call it on MX arguments
            qs, ps = ca.SX.sym("q", 6), ca.SX.sym("p", len(self.layout))
            cs, os_ = ca.SX.sym("c", len(self.column_names)), ca.SX.sym("o", 6)
            f = ca.Function("tool_point_sx", [qs, ps, cs, os_], [self.expression(qs, ps, cs, os_)])
            return f(q, p, c, ca.DM.zeros(6) if offset is None else offset)
        col = {name: c[k] for k, name in enumerate(self.column_names)}
        ch = self._chain0
        # gravity torques of the nominal arm at the encoder reading (as ModelInputs.tau)
        tau = self._gravity_torques(q, col["payload"])
        theta = [q[i] + 0 for i in range(6)]
        for e in self.model.effects:
            if isinstance(e, JointAngleEffect) and type(e) in _BASIS:
                v = p[self.layout.slice(e.name)]
                for k, (j, term) in enumerate(e.parameter_terms()):
                    theta[j - 1] = theta[j - 1] + v[k] * _BASIS[type(e)](q, tau, col, j, term)
        if offset is not None:
            theta = [theta[i] + offset[i] for i in range(6)]
        alpha = [float(ch.alpha[i]) for i in range(6)]
        a = [float(ch.a[i]) for i in range(6)]
        beta = [float(ch.beta[i]) for i in range(6)]
        d = [float(ch.d[i]) for i in range(6)]
        toff = [float(ch.theta_offset[i]) for i in range(6)]
        robot = self.model.robot
        base_R = ca.SX(robot.base_matrix[:3, :3])
        base_t = ca.SX(np.asarray(robot.base_translation, dtype=float))
        tool = ca.SX(self._tool0)
        for e in sorted(
            (e for e in self.model.effects if isinstance(e, ChainEffect)), key=lambda e: e.order
        ):
            v = p[self.layout.slice(e.name)]
            if isinstance(e, Geometric):
                # by name (docs/format.md, parameter names): row i has dalpha_i, da_i, dtheta_i,
                # dd_i or beta_{i-1}
                pos = {n: j for j, n in enumerate(self.layout.names[self.layout.slice(e.name)])}
                for i in range(6):
                    r = i + 1
                    if f"dalpha{r}" in pos:
                        alpha[i] = alpha[i] + v[pos[f"dalpha{r}"]]
                    if f"da{r}" in pos:
                        a[i] = a[i] + v[pos[f"da{r}"]]
                    if f"dtheta{r}" in pos:
                        toff[i] = toff[i] + v[pos[f"dtheta{r}"]]
                    if f"dd{r}" in pos:
                        d[i] = d[i] + v[pos[f"dd{r}"]]
                    if f"beta{r - 1}" in pos:
                        beta[i] = beta[i] + v[pos[f"beta{r - 1}"]]
                base_t = ca.vertcat(*(v[pos[n]] for n in ("bx", "by", "bz")))
                base_R = rodrigues(ca.vertcat(*(v[pos[n]] for n in ("brx", "bry", "brz"))))
                suffix = "" if "tx" in pos else str(self.model.targets[self.target])
                tool = tool + ca.vertcat(*(v[pos[f"t{c}{suffix}"]] for c in "xyz"))
            else:  # Thermal
                scale = 1 + v[0] * (col["temperature"] - REFERENCE_TEMPERATURE)
                a = [ai * scale for ai in a]
                d = [di * scale for di in d]
        Rs, os_ = _frames(alpha, beta, a, d, [theta[i] + toff[i] for i in range(6)])
        pb = os_[5] + Rs[5] @ tool
        return base_R @ pb + base_t

    def _gravity_torques(self, q, payload):
        """tau_i = z_i . sum_{k>=i} (c_k - o_i) x (m_k g) on the nominal arm (docs/format.md,
        parameter names: compliance)."""
        robot = self.model.robot
        ch = self._chain0
        Rs, os_ = _frames(
            [float(x) for x in ch.alpha],
            [float(x) for x in ch.beta],
            [float(x) for x in ch.a],
            [float(x) for x in ch.d],
            [q[i] + float(ch.theta_offset[i]) for i in range(6)],
        )
        g = ca.SX(np.asarray(robot.gravity, dtype=float))
        masses = robot.masses
        coms = robot.coms
        tool_pt = os_[5] + Rs[5] @ ca.SX(robot.tool_points[0])
        M: float | ca.SX = 0.0
        MC = ca.SX.zeros(3)
        tau_last_first = []
        for i in range(5, -1, -1):
            M = M + float(masses[i])
            MC = MC + float(masses[i]) * (os_[i] + Rs[i] @ ca.SX(coms[i]))
            if i == 5:
                M = M + payload
                MC = MC + payload * tool_pt
            lever = MC - M * os_[i]
            tau_last_first.append(ca.dot(Rs[i][:, 2], ca.cross(lever, g)))
        return tau_last_first[::-1]


# d theta_j / d parameter of each catalogued joint-angle effect, as CasADi expressions
def _basis_compliance(q, tau, col, j, term):
    return tau[j - 1]


def _basis_transmission(q, tau, col, j, term):
    return ca.sin(q[j - 1]) if term == "ts" else ca.cos(q[j - 1])


def _basis_cyclic(q, tau, col, j, term):
    # term "s17" / "c17": the sine / cosine of 17 q_j (arm.effects.Cyclic)
    angle = int(term[1:]) * q[j - 1]
    return ca.sin(angle) if term[0] == "s" else ca.cos(angle)


def _basis_scale(q, tau, col, j, term):
    return q[j - 1]


def _basis_backlash(q, tau, col, j, term):
    return -0.5 * col[f"dir{j}"]


def _basis_load_backlash(q, tau, col, j, term):
    # a dead band where the torque vanishes identically (tau_1, tau_6 of the seed arm), so that
    # round-off does not flip the side of the gap from one step to the next
    t, eps = tau[j - 1], LoadBacklash.zero_torque
    return ca.if_else(t > eps, 0.5, ca.if_else(t < -eps, -0.5, 0.0))


_BASIS = {
    Compliance: _basis_compliance,
    Transmission: _basis_transmission,
    Cyclic: _basis_cyclic,
    JointScale: _basis_scale,
    Backlash: _basis_backlash,
    LoadBacklash: _basis_load_backlash,
}


_CACHE: dict[tuple, ToolModel] = {}


def cached_tool_model(model: ErrorModel, target: int = 0) -> ToolModel:
    """A :class:`ToolModel` of ``model``, built once per process for each (description, effects,
    target): building the CasADi expressions takes a fraction of a second, evaluating them
    microseconds."""
    key = (model.robot.to_toml(), tuple(model.effect_names), model.targets, int(target))
    tm = _CACHE.get(key)
    if tm is None:
        if len(_CACHE) > 32:
            _CACHE.clear()
        tm = _CACHE[key] = ToolModel(model, target)
    elif tm.model is not model:
        tm = _rebind(tm, model)
    return tm


def _rebind(tm: ToolModel, model: ErrorModel) -> ToolModel:
    """The cached expressions for an equal model object (same layout and effects)."""
    clone = object.__new__(ToolModel)
    clone.__dict__.update(tm.__dict__)
    clone.model = model
    clone.layout = model.layout
    clone._custom = [
        e for e in model.effects if isinstance(e, JointAngleEffect) and type(e) not in _BASIS
    ]
    clone._b_q = BufferedFunction(tm._f_q)  # buffers of its own
    clone._b_p = BufferedFunction(tm._f_p)
    return clone
