"""The MuJoCo plant: a six-axis arm built in code (MjSpec) from a robot description with its *true*
geometry, driven by joint servos that follow velocity commands, with the hidden effects made by
physics wherever physics can make them.

Bodies follow the modified-DH rows exactly: body i sits at ``RotX(alpha_{i-1}) RotY(beta_{i-1})
TransX(a_{i-1}) RotZ(theta_offset_i) TransZ(d_i)`` in its parent and turns about its own z, so that
with rigid joints MuJoCo's ``site_xpos`` of the tool is the kinematic model's tool point of the same
arm (``arm.kinematics``), to rounding. A base body carries the base transform (measurement frame
<- robot base); the world frame is the measurement frame.

Each axis is a motor-side hinge (the encoder reads it) driven by a servo: an integrating position
loop (``intvelocity``, the reference integrates the commanded velocity within the joint limits)
with a velocity feed-forward loop, a torque limit on the joint, reflected rotor inertia
(armature), viscous and dry friction. The command is rate-limited to the axis' acceleration limit
and clipped to its velocity limit once per control step.

An *elastic* plant adds, per axis, a link-side hinge in series with the motor hinge, joined by the
gear mesh: a fixed tendon ``L_i = q_link_i - s_i q_motor_i`` with stiffness ``k_i`` (the joint
compliance ``c_i = 1/k_i``), a little mesh damping, and a dead band ``[c_i - gap_i/2, c_i +
gap_i/2]`` (the backlash). So gravity and payload really deflect the links, fast motion really
vibrates, and inside the gap the link is free: where gravity loads the joint it rests against the
loaded side; where the link-side bearing friction holds it, it lags its motor. Gear transmission
error (an eccentricity ``ts sin(q) + tc cos(q)``) and a gear-ratio error ``g q`` move the mesh's
rest position with the motor angle: once per control step the rest function is linearised at the
motor angle (``s_i`` and ``c_i`` above), exact to second order in the motion of one step. Cyclic
errors of higher orders (``a_s sin(k q) + a_c cos(k q)``, k per turn: the gears and encoders that
turn faster than the joint) add to the rest function; with them it is linearised again within a
control step, up to every physics step, wherever k times the motion of the step is not small (it
may be a radian).

Thermal growth: one arm temperature heats with the motors' losses and cools towards ambient; every
control step the link lengths a and d (nominal plus error) are scaled by ``1 + kappa (T - 20 degC)``
by moving the bodies (the base and the tool do not grow). The payload is a point mass at the tool
point that may change during an episode.

The ``discrete`` integrator (implicit in position and velocity) keeps stiff joints and servos stable
at 1 kHz with light wrist links.

It is one module, longer than most, because the plant is one MjSpec model: building it, driving its
servos and its hidden physics share the layout of its bodies, hinges and tendons.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from arm.constraints import Interval, check, constraints_of, declare, refuse
from arm.description import RobotDescription
from arm.effects import REFERENCE_TEMPERATURE
from arm.kinematics import gravity_torques
from arm.so3 import rot_x, rot_y, rot_z, rotation_matrix
from envs.errors import PlantError
from envs.simulator import mujoco

__all__ = [
    "RIGID_STIFFNESS",
    "Drive",
    "HiddenEffects",
    "Plant",
    "PlantError",
]

log = logging.getLogger(__name__)

RIGID_STIFFNESS = 1e9  # N*m/rad: an elastic plant's mesh where the scenario has no compliance
MESH_DAMPING_STIFFNESS = 1e6  # N*m/rad: mesh damping is sized for at most this stiffness
PHYSICS_DT = 0.001  # s
SUBSTEPS = 20  # physics steps per control step (50 Hz control)
# rad: the largest phase k * (motion between two linearisations) of a cyclic error of order k
# (its second-order error: 0.5 % of its size, 1.5e-6 rad at 0.3 mrad); beyond it a control step
# is split
CYCLIC_LINEAR_PHASE = 0.1
AMBIENT = 20.0  # degC
MAX_SPEED = 100.0  # rad/s: any hinge faster than this means the simulation has diverged

# Servo and drive-train defaults of the seed arm's class (about 6 kg payload, 1 m reach).
V_MAX = (1.2, 1.2, 1.5, 2.5, 2.5, 3.0)  # rad/s
A_MAX = (6.0, 6.0, 8.0, 12.0, 12.0, 15.0)  # rad/s^2
SERVO_BANDWIDTH = 2 * math.pi * 8.0  # rad/s, position loop
HOLD_POWER = 60.0  # W dissipated by an axis holding its full torque (copper losses)
KP_MIN = 2000.0  # N*m/rad: the light axes' position loop is stiffer than their inertia asks


def _add_scenery(spec: mujoco.MjSpec, r: RobotDescription) -> Any:
    """The light, the sky, the floor and the base the arm stands on; returns the base body."""
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.55, 0.55, 0.55]
    sky = spec.add_texture(name="sky", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX)
    sky.builtin = mujoco.mjtBuiltin.mjBUILTIN_GRADIENT
    sky.rgb1, sky.rgb2 = [0.93, 0.95, 0.98], [0.62, 0.68, 0.76]
    sky.width, sky.height = 256, 1536
    grid = spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D)
    grid.builtin = mujoco.mjtBuiltin.mjBUILTIN_CHECKER
    grid.rgb1, grid.rgb2 = [0.86, 0.87, 0.89], [0.78, 0.80, 0.83]
    grid.width, grid.height = 300, 300
    floor_mat = spec.add_material(name="floor", texrepeat=[8.0, 8.0], reflectance=0.0)
    floor_mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
    wb = spec.worldbody
    wb.add_light(pos=[0.5, -0.5, 3.0], dir=[-0.2, 0.2, -1.0], castshadow=False)
    wb.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[2.0, 2.0, 0.05],
        material="floor",
        contype=0,
        conaffinity=0,
    )
    base = wb.add_body(name="base")
    base.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[0.09, 0.5 * max(r.joints[0].d, 0.02), 0.0],
        pos=[0.0, 0.0, 0.5 * max(r.joints[0].d, 0.02)],
        rgba=[0.25, 0.25, 0.28, 1.0],
        contype=0,
        conaffinity=0,
    )
    return base


def _vec6(x, name: str) -> np.ndarray:
    a = np.array(np.broadcast_to(np.asarray(x, dtype=float), (6,)), dtype=float)
    if not np.all(np.isfinite(a) | np.isinf(a)) or np.any(np.isnan(a)):
        raise PlantError(f"{name} must be 6 numbers, got {x!r}")
    return a


@dataclass(frozen=True, eq=False)
class Drive:
    """Servo and drive-train constants of the six axes (SI units, all (6,) arrays).

    ``v_max``/``a_max`` limit the commanded velocity and its rate of change; ``torque_max`` limits
    the total servo torque on the motor hinge; ``armature`` is the reflected rotor inertia;
    ``kp``/``kv`` the position and velocity loop gains; ``damping``/``friction`` the motor side's
    viscous and dry friction.
    """

    v_max: np.ndarray
    a_max: np.ndarray
    torque_max: np.ndarray
    armature: np.ndarray
    kp: np.ndarray
    kv: np.ndarray
    damping: np.ndarray
    friction: np.ndarray


@dataclass(frozen=True, eq=False)
class HiddenEffects:
    """The physical magnitudes of a plant's hidden effects (SI units; arrays are per axis).

    ``stiffness`` of the gear mesh (N*m/rad; ``inf``: rigid), ``gap`` the whole backlash (rad),
    ``bearing_friction`` the link-side dry friction (N*m) that holds a link inside its gap,
    ``ts``/``tc`` the transmission error and ``g`` the gear-ratio error (rad, 1), ``cyclic`` the
    cyclic errors of higher orders, ``(joint, order, a_s, a_c)`` each (joint 1..6, k per turn,
    rad: ``a_s sin(k q) + a_c cos(k q)``, the ``cyclic`` effect's ``cs{joint}_{k}``,
    ``cc{joint}_{k}``), ``kappa`` the
    thermal expansion (1/K) with the arm starting at ``temperature0`` (degC), heating by ``heating``
    K per J of motor losses and cooling towards ambient with ``cooling_time`` (s); ``payload0`` (kg)
    at the tool point, changed to ``mass`` at each ``(time, mass)`` of ``payload_schedule``.
    """

    stiffness: np.ndarray = field(default_factory=lambda: np.full(6, np.inf))
    gap: np.ndarray = field(default_factory=lambda: np.zeros(6))
    bearing_friction: np.ndarray = field(default_factory=lambda: np.zeros(6))
    ts: np.ndarray = field(default_factory=lambda: np.zeros(6))
    tc: np.ndarray = field(default_factory=lambda: np.zeros(6))
    g: np.ndarray = field(default_factory=lambda: np.zeros(6))
    cyclic: tuple[tuple[int, int, float, float], ...] = ()
    mesh_damping_ratio: float = 0.05
    kappa: float = 0.0
    temperature0: float = AMBIENT
    heating: float = 0.0
    cooling_time: float = declare(600.0, Interval(float, 0.0, None, closed="neither", why="s"))
    payload0: float = declare(0.0, Interval(float, 0.0, None, why="kg"))
    payload_schedule: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        for name in ("stiffness", "gap", "bearing_friction", "ts", "tc", "g"):
            object.__setattr__(self, name, _vec6(getattr(self, name), name))
        terms = []
        for t in self.cyclic:
            ok = len(t) == 4
            if ok:
                j, k, a_s, a_c = t
                ok = (
                    j == int(j)
                    and 1 <= j <= 6
                    and k == int(k)
                    and k >= 1
                    and math.isfinite(a_s)
                    and math.isfinite(a_c)
                )
            if not ok:
                raise PlantError(
                    f"a cyclic error is (joint 1..6, order >= 1, a_s, a_c) in rad, got {t!r}"
                )
            terms.append((int(j), int(k), float(a_s), float(a_c)))
        object.__setattr__(self, "cyclic", tuple(terms))
        if np.any(self.stiffness <= 0):
            raise PlantError(f"stiffness must be > 0 (inf for rigid), got {self.stiffness}")
        if np.any(self.gap < 0) or np.any(self.bearing_friction < 0):
            raise PlantError("backlash gaps and bearing friction must be >= 0")
        if any(m < 0 for _, m in self.payload_schedule):
            raise PlantError("payload masses must be >= 0 kg")
        declared = constraints_of(HiddenEffects)  # the scalars' ranges (the arrays' are above)
        scalars = {k: getattr(self, k) for k in ("cooling_time", "payload0")}
        refuse(check(scalars, declared), PlantError)

    @property
    def needs_elastic(self) -> bool:
        """Whether a motor-side and a link-side hinge are needed (rigid joints are one hinge)."""
        return bool(
            np.any(np.isfinite(self.stiffness))
            or np.any(self.gap > 0)
            or np.any(self.ts)
            or np.any(self.tc)
            or np.any(self.g)
            or bool(self.cyclic)
        )

    @property
    def thermal(self) -> bool:
        return self.kappa != 0.0 or self.temperature0 != AMBIENT or self.heating != 0.0

    def replace(self, **kw) -> HiddenEffects:
        return replace(self, **kw)


# -- geometry -----------------------------------------------------------------------------------
def _quat(R: np.ndarray) -> np.ndarray:
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R).reshape(9))
    return q


def row_frames(robot: RobotDescription) -> tuple[np.ndarray, np.ndarray]:
    """Position (6, 3) and quaternion (6, 4) of each row's body in its parent (modified DH)."""
    m = robot.to_modified()
    pos = np.empty((6, 3))
    quat = np.empty((6, 4))
    for i, j in enumerate(m.joints):
        Rab = rot_x(j.alpha) @ rot_y(j.beta)
        pos[i] = Rab @ np.array([j.a, 0.0, j.d])
        quat[i] = _quat(Rab @ rot_z(j.theta_offset))
    return pos, quat


def _cylinder_inertia(mass: float, axis: np.ndarray, length: float, radius: float) -> np.ndarray:
    u = axis / np.linalg.norm(axis)
    perp = mass * (3 * radius**2 + length**2) / 12.0
    along = 0.5 * mass * radius**2
    return perp * (np.eye(3) - np.outer(u, u)) + along * np.outer(u, u)


def _link_segments(robot: RobotDescription) -> list[np.ndarray]:
    """For each link i (1..6), the next frame's origin (or the tool point) in frame i."""
    m = robot.to_modified()
    out = []
    for i in range(6):
        if i < 5:
            nxt = m.joints[i + 1]
            out.append(rot_x(nxt.alpha) @ rot_y(nxt.beta) @ np.array([nxt.a, 0.0, nxt.d]))
        else:
            out.append(m.tool_points[0].copy())
    return out


# -- the plant ----------------------------------------------------------------------------------
class Plant:
    """A MuJoCo arm (see the module docstring). ``elastic`` selects the two-hinge drive train,
    needed by compliance, transmission and backlash; :meth:`configure` sets the true geometry and
    the hidden effects (values can change between episodes, the structure cannot)."""

    def __init__(
        self,
        robot: RobotDescription,
        elastic: bool = False,
        drive: Drive | None = None,
        physics_dt: float = PHYSICS_DT,
        substeps: int = SUBSTEPS,
    ) -> None:
        self.nominal = robot.to_modified()
        if not self.nominal.has_mass_model:
            raise PlantError(f"robot {robot.name!r} has no masses: the plant needs a mass model")
        if self.nominal.couplings:
            raise PlantError(
                f"robot {robot.name!r} has coupled joints ({len(self.nominal.couplings)}): the "
                "MuJoCo plant drives each joint on its own and does not represent them"
            )
        if self.nominal.extra_joints:
            raise PlantError(
                f"robot {robot.name!r} stands on extra joints "
                f"({', '.join(self.nominal.extra_names)}): the MuJoCo plant builds the arm "
                "alone and does not represent them"
            )
        self.elastic = bool(elastic)
        self.physics_dt = float(physics_dt)
        self.substeps = int(substeps)
        self.dt = self.physics_dt * self.substeps
        self.spec = self._build_spec()
        self.model = self.spec.compile()
        self.data = mujoco.MjData(self.model)
        self._index()
        self.drive = drive if drive is not None else self.default_drive()
        self._apply_drive(self.drive)
        self._v_ref = np.zeros(6)
        self._dv = np.zeros(6)
        self._lo = np.zeros(6)
        self._hi = np.zeros(6)
        self.dirs = np.ones(6)
        self._J_link: np.ndarray | None = None
        self.configure(self.nominal, HiddenEffects())

    # -- building ---------------------------------------------------------------------------
    def _build_spec(self) -> mujoco.MjSpec:
        r = self.nominal
        spec = mujoco.MjSpec()
        spec.modelname = f"sixaxis_{r.name}"
        spec.compiler.degree = False
        spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
        spec.compiler.autolimits = True
        opt = spec.option
        opt.timestep = self.physics_dt
        opt.integrator = mujoco.mjtIntegrator.mjINT_DISCRETE
        opt.gravity = np.asarray(r.gravity, dtype=float)
        opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
        # a blown-up state is kept (and detected by step()), not silently reset to qpos0
        opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
        spec.visual.quality.offsamples = 0
        spec.visual.quality.shadowsize = 0
        spec.stat.center = np.array([0.3, 0.0, 0.5])
        spec.stat.extent = 1.2
        base = _add_scenery(spec, r)
        last = self._add_chain(base)
        self._add_tool_and_drives(spec, last)
        return spec

    def _add_chain(self, base: Any) -> Any:
        """The arm's bodies from the base, one per DH row (with a link body behind a gear where
        the drive is elastic), their inertias and drawn shapes; returns the last link."""
        r = self.nominal
        pos, quat = row_frames(r)
        segs = _link_segments(r)
        colours = ([0.95, 0.55, 0.1, 1.0], [0.9, 0.9, 0.92, 1.0])
        parent = base
        for i, j in enumerate(r.joints):
            k = i + 1
            lim = [j.lower, j.upper]
            b = parent.add_body(name=f"row{k}", pos=pos[i], quat=quat[i])
            b.add_joint(
                name=f"motor{k}",
                type=mujoco.mjtJoint.mjJNT_HINGE,
                axis=[0.0, 0.0, 1.0],
                range=lim,
                limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            )
            if self.elastic:
                # the motor body is the gear's input side: no mass of its own (the rotor is armature)
                b.mass = 1e-6
                b.inertia = [1e-9, 1e-9, 1e-9]
                b.ipos = [0.0, 0.0, 0.0]
                link = b.add_body(name=f"link{k}")
                link.add_joint(
                    name=f"link{k}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0.0, 0.0, 1.0]
                )
            else:
                link = b
            mass = max(j.mass, 1e-6)
            seg = segs[i]
            length = float(np.linalg.norm(seg))
            axis = seg if length > 0.05 else np.array([0.0, 0.0, 1.0])
            radius = 0.035 + 0.004 * min(j.mass, 10.0)
            I = _cylinder_inertia(mass, axis, max(length, 0.1), radius)
            link.mass = mass
            link.ipos = np.array(j.com, dtype=float)
            link.fullinertia = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
            link.explicitinertial = True
            rad = 0.6 * radius
            link.add_geom(
                type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                fromto=[0.0, 0.0, -0.06, 0.0, 0.0, 0.06],
                size=[rad * 1.25, 0.0, 0.0],
                rgba=colours[0],
                contype=0,
                conaffinity=0,
                group=1,
            )
            if length > 1e-6:
                link.add_geom(
                    type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                    fromto=[0.0, 0.0, 0.0, *seg],
                    size=[rad, 0.0, 0.0],
                    rgba=colours[1] if i < 5 else [0.3, 0.3, 0.33, 1.0],
                    contype=0,
                    conaffinity=0,
                    group=1,
                )
            parent = link
        return parent

    def _add_tool_and_drives(self, spec: mujoco.MjSpec, last: Any) -> None:
        """The tool site and the payload body on the last link, the gears' tendons (elastic
        drives) and the position and velocity servos."""
        r = self.nominal
        tool = r.tool_points[0]
        last.add_site(name="tool", pos=tool, size=[0.012, 0, 0], rgba=[0.1, 0.6, 1.0, 1.0])
        payload = last.add_body(name="payload", pos=tool)
        payload.mass = 0.0
        payload.ipos = [0.0, 0.0, 0.0]
        payload.inertia = [0.0, 0.0, 0.0]
        payload.explicitinertial = True
        if self.elastic:
            for k in range(1, 7):
                mesh = spec.add_tendon(name=f"mesh{k}")
                mesh.wrap_joint(f"link{k}", 1.0)
                mesh.wrap_joint(f"motor{k}", 0.0)
                mesh.stiffness = [RIGID_STIFFNESS, 0.0, 0.0]
                mesh.springlength = [0.0, 0.0]
                bearing = spec.add_tendon(name=f"bearing{k}")
                bearing.wrap_joint(f"motor{k}", 1.0)
                bearing.wrap_joint(f"link{k}", 1.0)
                # hard dry friction: MuJoCo's friction is regularised, and at the default
                # impedance a link held in its gap by friction alone creeps through it in ~1 s
                bearing.solimp_friction = [0.9999, 0.9999, 0.001, 0.5, 2.0]
        for k in range(1, 7):
            a = spec.add_actuator(name=f"servo{k}", target=f"motor{k}")
            a.trntype = mujoco.mjtTrn.mjTRN_JOINT
            a.set_to_intvelocity(kp=1.0, kv=0.0)
            a.actlimited = mujoco.mjtLimited.mjLIMITED_TRUE
            a.actrange = [r.joints[k - 1].lower, r.joints[k - 1].upper]
        for k in range(1, 7):
            a = spec.add_actuator(name=f"velocity{k}", target=f"motor{k}")
            a.trntype = mujoco.mjtTrn.mjTRN_JOINT
            a.set_to_velocity(kv=1.0)

    def _index(self) -> None:
        m = self.model

        def jid(name):
            return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)

        def as_index(ix):
            ix = np.asarray(ix, dtype=int)
            step = ix[1] - ix[0]
            if np.all(np.diff(ix) == step):
                return slice(int(ix[0]), int(ix[-1]) + 1, int(step))
            return ix

        motor = [jid(f"motor{k}") for k in range(1, 7)]
        self._motor_jnt = np.array(motor)
        self.iq = as_index(m.jnt_qposadr[motor])  # encoder positions in qpos
        self.iv = as_index(m.jnt_dofadr[motor])  # motor velocities in qvel
        if self.elastic:
            link = [jid(f"link{k}") for k in range(1, 7)]
            self.il = as_index(m.jnt_qposadr[link])
            self.ilv = as_index(m.jnt_dofadr[link])
            mesh = [
                mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TENDON, f"mesh{k}") for k in range(1, 7)
            ]
            bearing = [
                mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TENDON, f"bearing{k}") for k in range(1, 7)
            ]
            self._mesh = np.array(mesh)
            self._bearing = np.array(bearing)
            # the motor's coefficient in each mesh tendon (the second wrap entry)
            self._mesh_coef = m.tendon_adr[self._mesh] + 1
        self.tool_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tool")
        self._rows = np.array(
            [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"row{k}") for k in range(1, 7)]
        )
        self._base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "base")
        self._payload = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "payload")
        self._act_adr = m.actuator_actadr[:6].copy()
        # views into MjData (its buffers never move): the step reads them without re-wrapping
        d = self.data
        self._ctrl = d.ctrl
        self._ctrl_pos, self._ctrl_vel = d.ctrl[:6], d.ctrl[6:12]
        self._qvel = d.qvel
        self.q_view = d.qpos[self.iq] if isinstance(self.iq, slice) else None
        self.qd_view = d.qvel[self.iv] if isinstance(self.iv, slice) else None
        self.tool_xpos = d.site_xpos[self.tool_site]
        self.tool_xmat = d.site_xmat[self.tool_site]

    # -- the drive ------------------------------------------------------------------------------
    def _home(self) -> np.ndarray:
        return 0.5 * (self.nominal.lower + self.nominal.upper)

    def link_inertia(self, q: np.ndarray | None = None) -> np.ndarray:
        """The inertia (6,) that each motor hinge drives at ``q`` (default the middle of the
        limits), without armature: the diagonal of MuJoCo's mass matrix."""
        d = mujoco.MjData(self.model)
        d.qpos[self.iq] = self._home() if q is None else q
        mujoco.mj_forward(self.model, d)
        M = np.zeros((self.model.nv, self.model.nv))
        mujoco.mj_fullM(self.model, d, M)
        diag = np.diag(M)[self.iv] - self.model.dof_armature[self.iv]
        return diag

    def default_drive(self) -> Drive:
        """Servo constants for this arm: armature half the link inertia (at the middle of the
        limits), a critically damped position loop of ``SERVO_BANDWIDTH`` (at least ``KP_MIN``
        stiff), torque limits 2.5x the largest gravity torque (3 kg payload) plus the inertial
        torque at ``a_max``."""
        J = self.link_inertia()
        armature = np.maximum(0.5 * J, 0.02)
        inertia = J + armature
        rng = np.random.default_rng(0)
        q = rng.uniform(self.nominal.lower, self.nominal.upper, size=(512, 6))
        grav = np.abs(gravity_torques(self.nominal, q, payload=3.0)).max(axis=0)
        a_max = np.array(A_MAX)
        torque_max = np.maximum(2.5 * grav + inertia * a_max, 10.0)
        kp = np.maximum(inertia * SERVO_BANDWIDTH**2, KP_MIN)
        return Drive(
            v_max=np.array(V_MAX),
            a_max=a_max,
            torque_max=torque_max,
            armature=armature,
            kp=kp,
            kv=2.0 * np.sqrt(kp * inertia),  # critically damped
            damping=0.004 * torque_max,
            friction=0.012 * torque_max,
        )

    def _apply_drive(self, drive: Drive) -> None:
        m = self.model
        iv = self.iv
        m.dof_armature[iv] = drive.armature
        m.dof_damping[iv] = drive.damping
        m.dof_frictionloss[iv] = drive.friction
        for k in range(6):
            # intvelocity: force = kp * act - kp * q ; velocity: force = kv * ctrl - kv * qdot
            m.actuator_gainprm[k, 0] = drive.kp[k]
            m.actuator_biasprm[k, 1] = -drive.kp[k]
            m.actuator_biasprm[k, 2] = 0.0
            m.actuator_gainprm[6 + k, 0] = drive.kv[k]
            m.actuator_biasprm[6 + k, 2] = -drive.kv[k]
            jnt = self._motor_jnt[k]
            m.jnt_actfrclimited[jnt] = 1
            m.jnt_actfrcrange[jnt] = (-drive.torque_max[k], drive.torque_max[k])
        self._a_dt = drive.a_max * self.dt
        self._v_max = np.asarray(drive.v_max, dtype=float)
        self._max_speed2 = MAX_SPEED**2

    # -- configuration --------------------------------------------------------------------------
    def configure(self, robot: RobotDescription, effects: HiddenEffects) -> None:
        """Set the true geometry (a description with the errors folded in: DH rows, Hayati beta,
        base and tool) and the hidden effects. The state is reset; call :meth:`place` next."""
        r = robot.to_modified()
        if effects.needs_elastic and not self.elastic:
            raise PlantError(
                "these hidden effects (compliance, transmission or backlash) need an elastic "
                "plant: Plant(robot, elastic=True)"
            )
        m = self.model
        self.robot = r
        self.effects = effects
        pos, quat = row_frames(r)
        self._row_pos = pos
        m.body_pos[self._rows] = pos
        m.body_quat[self._rows] = quat
        m.body_pos[self._base] = r.base_translation
        m.body_quat[self._base] = _quat(rotation_matrix(np.array(r.base_rotation)))
        m.site_pos[self.tool_site] = r.tool_points[0]
        m.body_pos[self._payload] = r.tool_points[0]
        if self.elastic:
            k = np.where(np.isfinite(effects.stiffness), effects.stiffness, RIGID_STIFFNESS)
            if self._J_link is None:
                self._J_link = self.link_inertia_link_side()
            J = self._J_link
            m.tendon_stiffness[self._mesh] = k
            # damping of the elastic mode; a stiff mesh needs none (the integrator is implicit)
            # and would drag a link across its gap with the motor
            k_damped = np.minimum(k, MESH_DAMPING_STIFFNESS)
            m.tendon_damping[self._mesh] = 2.0 * effects.mesh_damping_ratio * np.sqrt(k_damped * J)
            m.tendon_frictionloss[self._bearing] = effects.bearing_friction
            self._stiffness = k
        self._transmission = self.elastic and bool(
            np.any(effects.ts) or np.any(effects.tc) or np.any(effects.g) or effects.cyclic
        )
        # cyclic errors: (joint index, order, a_s, a_c) as arrays, relinearised every physics step
        cyc = np.array(effects.cyclic, dtype=float).reshape(-1, 4)
        self._cyclic = (cyc[:, 0].astype(int) - 1, cyc[:, 1], cyc[:, 2], cyc[:, 3])
        self._cyclic_kmax = np.zeros(6)  # the highest order of each joint
        np.maximum.at(self._cyclic_kmax, self._cyclic[0], self._cyclic[1])
        self._per_physics_step = self.elastic and bool(effects.cyclic)
        self._thermal = effects.thermal
        self._schedule = sorted(effects.payload_schedule)
        self._tau_max = np.asarray(self.drive.torque_max, dtype=float)
        self.reset()

    def link_inertia_link_side(self) -> np.ndarray:
        """The inertia (6,) about each link-side hinge at the middle of the limits."""
        if not self.elastic:
            return self.link_inertia()
        d = mujoco.MjData(self.model)
        d.qpos[self.iq] = self._home()
        mujoco.mj_forward(self.model, d)
        M = np.zeros((self.model.nv, self.model.nv))
        mujoco.mj_fullM(self.model, d, M)
        return np.diag(M)[self.ilv]

    def reset(self) -> None:
        """Zero state at the nominal temperature and initial payload (then :meth:`place`)."""
        mujoco.mj_resetData(self.model, self.data)
        self.temperature = float(self.effects.temperature0)
        self.payload = -1.0
        self.set_payload(self.effects.payload0)
        self._next_payload = 0
        self._apply_temperature()
        self._v_ref[:] = 0.0
        self.dirs[:] = 1.0
        self.energy = 0.0

    def set_payload(self, mass: float) -> None:
        """Change the payload (kg), a point mass at the tool point."""
        mass = float(mass)
        if mass == self.payload:
            return
        m = self.model
        m.body_mass[self._payload] = mass
        m.body_ipos[self._payload] = 0.0  # at the tool point
        # a small sphere (r = 2 cm) so that the mass matrix stays well defined
        m.body_inertia[self._payload] = 0.4 * mass * 0.02**2
        self.payload = mass
        # derived constants (subtree masses...); mj_setConst works on a scratch state because it
        # overwrites the state it is given
        mujoco.mj_setConst(m, mujoco.MjData(m))

    def _apply_temperature(self) -> None:
        s = 1.0 + self.effects.kappa * (self.temperature - REFERENCE_TEMPERATURE)
        self.model.body_pos[self._rows] = self._row_pos * s

    # -- state ------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def q(self) -> np.ndarray:
        """Encoder readings (6,) rad: the motor-side hinges (a copy)."""
        return self.data.qpos[self.iq].copy()

    @property
    def qd(self) -> np.ndarray:
        return self.data.qvel[self.iv].copy()

    @property
    def theta(self) -> np.ndarray:
        """The link angles (6,): motor plus link-side deflection (theta offsets excluded)."""
        if not self.elastic:
            return self.q
        return self.data.qpos[self.iq] + self.data.qpos[self.il]

    def tool_point(self) -> np.ndarray:
        """The true tool point (3,) in the measurement (world) frame, m (a copy)."""
        return self.tool_xpos.copy()

    def tool_frame(self) -> np.ndarray:
        """The true rotation (3, 3) of the last frame (the link that carries the tool), world
        <- last frame (a copy): what a 6-DoF probe on the flange turns with."""
        return self.tool_xmat.reshape(3, 3).copy()

    def gravity_torques(self) -> np.ndarray:
        """MuJoCo's gravity torques on the motor hinges at rest, with the sign of docs/format.md
        (compliance): minus qfrc_bias."""
        d = mujoco.MjData(self.model)
        d.qpos[:] = self.data.qpos
        mujoco.mj_forward(self.model, d)
        return -d.qfrc_bias[self.iv]

    def _mesh_rest(self, qm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The mesh's rest function r(q) = ts sin q + tc cos q + g q (+ the cyclic errors),
        and its slope."""
        e = self.effects
        s, c = np.sin(qm), np.cos(qm)
        r, slope = e.ts * s + e.tc * c + e.g * qm, e.ts * c - e.tc * s + e.g
        if e.cyclic:
            j, k, a_s, a_c = self._cyclic
            ks, kc = np.sin(k * qm[j]), np.cos(k * qm[j])
            r = r + np.bincount(j, a_s * ks + a_c * kc, minlength=6)
            slope = slope + np.bincount(j, k * (a_s * kc - a_c * ks), minlength=6)
        return r, slope

    def _set_mesh(self, qm: np.ndarray) -> None:
        """Linearise the mesh's rest position at the motor angles ``qm`` (once a control step)."""
        m = self.model
        r, slope = self._mesh_rest(qm)
        centre = r - slope * qm
        half = 0.5 * self.effects.gap
        m.wrap_prm[self._mesh_coef] = -slope
        m.tendon_lengthspring[self._mesh, 0] = centre - half
        m.tendon_lengthspring[self._mesh, 1] = centre + half

    def place(
        self,
        q: np.ndarray,
        dirs: np.ndarray | None = None,
        settle: float = 0.1,
        static: bool = True,
    ) -> None:
        """Put the arm at rest with the encoders reading ``q``: the servo's reference is set so
        that it holds q against gravity, each link at its static deflection (against the loaded
        side of its gap where gravity exceeds the bearing friction, else lagging its last motion
        ``dirs``), then ``settle`` seconds of physics; the clock restarts at zero. With
        ``static=False`` the links start undeflected and the physics alone finds their rest."""
        q = np.asarray(q, dtype=float).reshape(6)
        m, d = self.model, self.data
        if dirs is not None:
            self.dirs[:] = np.where(np.asarray(dirs) < 0, -1.0, 1.0)
        d.qpos[:] = 0.0
        d.qvel[:] = 0.0
        d.qpos[self.iq] = q
        self._v_ref[:] = 0.0
        d.ctrl[:] = 0.0
        if self.elastic:
            self._set_mesh(q)
            r, _ = self._mesh_rest(q)
            d.qpos[self.il] = r
            half = 0.5 * self.effects.gap
            f = self.effects.bearing_friction
            for _ in range(6 if static else 0):
                mujoco.mj_forward(m, d)
                tau = -d.qfrc_bias[self.ilv]
                loaded = np.abs(tau) > f
                side = np.where(loaded, np.sign(tau), -self.dirs)
                defl = np.where(loaded, tau / self._stiffness, 0.0)
                d.qpos[self.il] = r + side * half + defl
        mujoco.mj_forward(m, d)
        # the servo's reference sits where its position loop holds q against gravity
        hold = d.qfrc_bias[self.iv] - d.qfrc_passive[self.iv]
        d.act[self._act_adr] = q + hold / self.drive.kp
        if settle > 0:
            mujoco.mj_step(m, d, nstep=max(1, round(settle / self.physics_dt)))
            d.qvel[:] = 0.0
        d.time = 0.0
        mujoco.mj_forward(m, d)

    # -- stepping ---------------------------------------------------------------------------
    def step(self, v_cmd: np.ndarray) -> bool:
        """One control step: rate- and velocity-limit the commanded joint velocities (6,), rad/s,
        and run the physics for ``substeps`` steps with the effects updated once. Returns False
        if the simulation diverged (MuJoCo reset it, or a hinge is absurdly fast)."""
        m, d = self.model, self.data
        dv = self._dv
        np.subtract(v_cmd, self._v_ref, out=dv)
        np.minimum(dv, self._a_dt, out=dv)
        np.maximum(dv, -self._a_dt, out=dv)
        v = self._v_ref
        v += dv
        np.minimum(v, self._v_max, out=v)
        np.maximum(v, -self._v_max, out=v)
        self._ctrl_pos[:] = v
        self._ctrl_vel[:] = v
        # cyclic errors of high order: where k times the motion of this step is not small, the
        # rest function is relinearised within the step, at most every physics step (below)
        pieces = 1
        if self._per_physics_step:
            speed = np.maximum(np.abs(v), np.abs(d.qvel[self.iv]))
            phase = float(np.max(self._cyclic_kmax * speed)) * self.dt
            pieces = min(self.substeps, max(1, math.ceil(phase / CYCLIC_LINEAR_PHASE)))
        if self._transmission and pieces == 1:
            self._set_mesh(d.qpos[self.iq])
        if self._schedule and self._next_payload < len(self._schedule):
            t_next, mass = self._schedule[self._next_payload]
            if d.time + 0.5 * self.physics_dt >= t_next:
                self.set_payload(mass)
                self._next_payload += 1
        # the direction of each axis' last motion, as its controller commanded it
        if v.all():
            np.sign(v, out=self.dirs)
        else:
            np.copyto(self.dirs, np.sign(v), where=v != 0.0)
        if pieces > 1:
            for k in range(pieces):
                self._set_mesh(d.qpos[self.iq])
                n = (k + 1) * self.substeps // pieces - k * self.substeps // pieces
                mujoco.mj_step(m, d, nstep=n)
        else:
            mujoco.mj_step(m, d, nstep=self.substeps)
        if self._thermal:
            self._heat()
        # positions (site_xpos) of the state just reached, not of the last substep's start
        mujoco.mj_kinematics(m, d)
        qv = self._qvel
        return float(qv @ qv) < self._max_speed2  # NaN and inf fail the comparison too

    def _heat(self) -> None:
        d = self.data
        tau = d.qfrc_actuator[self.iv]
        power = float(
            np.abs(tau * d.qvel[self.iv]).sum() + HOLD_POWER * ((tau / self._tau_max) ** 2).sum()
        )
        self.energy += power * self.dt
        e = self.effects
        self.temperature += self.dt * (
            e.heating * power - (self.temperature - AMBIENT) / e.cooling_time
        )
        self._apply_temperature()

    def diverged(self) -> bool:
        """Whether the simulation has blown up (non-finite state, absurd speed, or MuJoCo reset
        it after a bad acceleration)."""
        d = self.data
        v = d.qvel
        if not np.isfinite(v).all() or not np.isfinite(d.qpos).all():
            return True
        if np.abs(v).max(initial=0.0) > MAX_SPEED:
            return True
        w = d.warning
        return (
            w[mujoco.mjtWarning.mjWARN_BADQACC].number > 0
            or w[mujoco.mjtWarning.mjWARN_BADQVEL].number > 0
            or w[mujoco.mjtWarning.mjWARN_BADQPOS].number > 0
        )
