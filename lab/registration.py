"""Registration: where the measurements say the nominal arm stands, in closed form.

A large unknown base transform (a laser tracker stands metres away, rotated anyhow) and tool
offsets (a reflector hundreds of millimetres off the flange) are initialised before any
iteration: alternately, Kabsch's rotation of the nominal chain's points onto the measured ones
(:meth:`scipy.spatial.transform.Rotation.align_vectors`) and linear least squares for the base
translation and every target's tool offset given that rotation. Each step lowers the sum of
squares, so it converges from a tool hundreds of millimetres off.

    p = register_base(model, inputs, xyz, model.nominal())
    p0 = nominal_parameters(model, inputs, xyz)     # the "before" of a calibration
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from arm.effect_api import ModelInputs
from arm.errormodel import ErrorModel
from arm.kinematics import link_frames
from arm.so3 import rotation_vector
from lab.blocks import Blocks

__all__ = ["nominal_parameters", "register_base", "tool_indices"]


def register_base(
    model: ErrorModel,
    inputs: ModelInputs,
    xyz: np.ndarray,
    params: np.ndarray,
    tools: bool = True,
    iterations: int = 100,
) -> np.ndarray:
    """Closed-form initial base transform (and tool offsets) for a geometric model.

    Alternates Kabsch's rotation of the chain's points onto ``xyz`` and linear least squares for
    the base translation and each target's tool point given the rotation; each step lowers the sum
    of squares, so it converges from a tool hundreds of millimetres off. Returns ``params`` with the
    base (and tool) parameters replaced."""
    lay = model.layout
    p = np.array(params, dtype=float)
    st = model.state(inputs, p)
    # the last frame of every pose, block by block (all seven frames of 200k poses: 130 MB)
    o6, R6 = np.empty((inputs.n, 3)), np.empty((inputs.n, 3, 3))
    for sl, part in Blocks(model, inputs):
        st_b = model.state(part, p)
        f = link_frames(st_b.chain, model.joint_angles(part, p))
        o6[sl], R6[sl] = f.o[:, 6], f.R[:, 6]
    tool = st.tools.copy()
    tgt = inputs.target
    n, K = inputs.n, len(model.targets)
    rows = np.arange(n)
    R = st.base_R
    t = st.base_t
    for _ in range(iterations):
        pts = o6 + np.einsum("nij,nj->ni", R6, tool[tgt])
        pc, mc = pts.mean(axis=0), xyz.mean(axis=0)
        rot, _ = Rotation.align_vectors(xyz - mc, pts - pc)
        R = rot.as_matrix()
        t = mc - R @ pc
        if not tools:
            break
        # xyz - R o6 = R R6 tool[target] + t, linear in (t, tools)
        A = np.zeros((n, 3, 3 + 3 * K))
        A[:, :, :3] = np.eye(3)
        RR6 = np.einsum("ij,njk->nik", R, R6)
        for k in range(K):
            A[rows[tgt == k], :, 3 + 3 * k : 6 + 3 * k] = RR6[tgt == k]
        b = xyz - o6 @ R.T
        # solve for the change from the current tools so that unseen directions stay put
        b = b - np.einsum("nij,nj->ni", RR6, tool[tgt])
        A2 = A.reshape(-1, 3 + 3 * K)
        sol, *_ = np.linalg.lstsq(A2.T @ A2, A2.T @ b.reshape(-1), rcond=None)
        t = sol[:3]
        step = sol[3:].reshape(K, 3)
        tool = tool + step
        if np.max(np.abs(step)) < 1e-10:
            break
    names = lay.names
    geo = lay.slice("geometric")
    for name, v in zip(("bx", "by", "bz"), t, strict=True):
        p[lay.index(name)] = v
    for name, v in zip(("brx", "bry", "brz"), rotation_vector(R), strict=True):
        p[lay.index(name)] = v
    if tools:
        tool_names = [x for x in names[geo] if x[:1] == "t" and x[1:2] in ("x", "y", "z")]
        idx = lay.indices(tool_names).reshape(K, 3)
        p[idx] += tool - st.tools
    return p


def tool_indices(model: ErrorModel) -> np.ndarray:
    """The indices of the geometric model's tool-point parameters (``tx``, ``ty``, ``tz``, per
    target)."""
    names = model.layout.names[model.layout.slice("geometric")]
    return model.layout.indices([n for n in names if n[:1] == "t" and n[1:2] in ("x", "y", "z")])


def nominal_parameters(model: ErrorModel, inputs: ModelInputs, xyz: np.ndarray) -> np.ndarray:
    """The nominal parameter vector with the base transform and tool offsets registered in closed
    form (:func:`register_base`): the "before" of a calibration, the nominal arm placed where the
    measurements say it stands (without it, data in a laser tracker's frame would be metres off).
    The registration is kept only where it lowers the RMS."""
    p = model.nominal()
    if "geometric" not in model.layout.effects:
        return p
    p_reg = register_base(model, inputs, xyz, p)
    before = np.sum((model.predict(inputs, p) - xyz) ** 2)
    after = np.sum((model.predict(inputs, p_reg) - xyz) ** 2)
    return p_reg if after < before else p
