"""The calibration of a robot's extra joints (:mod:`arm.extra_joints`): a lifting column's or a
track's scale and the tilt of its axis, a rotary table's scale."""

from __future__ import annotations

import numpy as np

from arm.description import RobotDescription
from arm.effect_api import ChainState, ModelInputs, Sensitivities
from arm.effects.base import ChainEffect
from arm.extra_joints import ExtraJoint, tilt_axis_jacobian

__all__ = ["ExtraJoints"]

#: parameter families: scale (1), and a prismatic joint's tilt about its two normals (rad)
SCALE, TILTS = "xs_", ("xt1_", "xt2_")


def _slots(robot: RobotDescription, names) -> list[tuple[int, ExtraJoint, str]]:
    """(index of the joint, the joint, the family) of each parameter name."""
    by_name = {j.name: (k, j) for k, j in enumerate(robot.extra_joints)}
    out = []
    for n in names:
        family = next(f for f in (SCALE, *TILTS) if n.startswith(f))
        k, j = by_name[n[len(family) :]]
        out.append((k, j, family))
    return out


class ExtraJoints(ChainEffect):
    """Each extra joint's scale ``xs_NAME`` (the value moved is ``v (1 + xs)``) and, for a
    prismatic one, the tilt of its axis ``xt1_NAME``, ``xt2_NAME`` (rad, about the two normals of
    :func:`arm.extra_joints.normals`: x then y for a vertical column)."""

    name = "extra_joints"
    order = 5
    needs_extra_joints = True
    typical = {"xs": (1e-4, 2e-3), "xt": (5e-5, 1e-3)}
    bounds = {"xs": 0.02, "xt": 0.01}
    description = "extra joints before the arm's base: each one's scale, a prismatic one's tilt"
    example = "extra_joints"

    def parameter_names(self, robot, targets):
        out = []
        for j in robot.extra_joints:
            out.append(f"{SCALE}{j.name}")
            if j.kind == "prismatic":
                out += [f"{t}{j.name}" for t in TILTS]
        return out

    def _names(self, state: ChainState) -> list[str]:
        return self.parameter_names(state.robot, state.targets)

    def apply(self, inputs: ModelInputs | None, values: np.ndarray, state: ChainState):
        k = len(state.robot.extra_joints)
        scale, tilt = np.zeros(k), np.zeros((k, 2))
        for v, (i, _, family) in zip(values, _slots(state.robot, self._names(state)), strict=True):
            if family == SCALE:
                scale[i] = v
            else:
                tilt[i, TILTS.index(family)] = v
        return state.replace(extra_scale=scale, extra_tilt=tilt)

    def jacobian(self, inputs, values, sens):
        return self._jacobian_from_into(inputs, values, sens)

    def jacobian_into(self, inputs: ModelInputs, values, sens: Sensitivities, out) -> bool:
        st = sens.state
        extra = st.extra_placement()
        if extra is None or inputs.extra is None:
            out[...] = 0.0
            return True
        B_R, B_t = st.replace(extra_values=None).pose_base(sens.station)
        raw = inputs.extra
        tilt = st.extra_tilt if st.extra_tilt is not None else np.zeros((len(raw[0]), 2))
        for c, (i, joint, family) in enumerate(_slots(st.robot, self._names(st))):
            W = B_R @ extra.joint_R[i]  # (N, 3, 3): the joint's frame in the measurement frame
            if family == SCALE:
                axis = W @ extra.axis[i]  # (N, 3)
                if joint.kind == "prismatic":
                    col = np.zeros_like(axis) if sens.angular else axis
                elif sens.angular:
                    col = axis
                else:
                    jt = extra.joint_t[i]
                    o = B_t + (jt @ B_R.T if B_R.ndim == 2 else np.einsum("nij,nj->ni", B_R, jt))
                    col = np.cross(axis, sens.point.T - o)
                out[c] = (col * raw[:, i, None]).T
            else:
                dA = tilt_axis_jacobian(joint, tilt[i])[:, TILTS.index(family)]
                col = np.zeros((inputs.n, 3)) if sens.angular else W @ dA * extra.moved[:, i, None]
                out[c] = col.T
        return True
