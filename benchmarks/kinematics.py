"""Kinematics speed, side by side with Pinocchio on the same arm (the seed arm, docs/format.md):

* batched tool-point forward kinematics (poses/s) for N = 1e3, 1e4, 1e5 against Pinocchio's
  per-pose Python loop (the fastest of three reasonable ways to get the tool point);
* the full identification Jacobian of 1,000 poses (geometric: 33 columns; geometric + compliance:
  39) in ms, against Pinocchio computing the same columns per pose from its frame kinematic
  regressor (``computeFrameKinematicRegressor``, mapped onto the DH parameters) and, for
  compliance, ``computeFrameJacobian`` times the gravity torques of ``computeGeneralizedGravity``.

Both sides' results are checked against each other before they are timed. Writes the
``kinematics`` section of results/benchmarks.md. Run: ``python benchmarks/kinematics.py``.
"""

from __future__ import annotations

import argparse
import gc
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from arm.description import RobotDescription, seed_robot
from arm.errormodel import ErrorModel
from arm.kinematics import Chain, tool_points
from arm.sampling import sample_poses
from benchmarks._report import machine, write_section


def timed(fn, repeats: int) -> float:
    """Median wall time (s) of ``repeats`` calls, after one warm-up call, GC off."""
    fn()
    times = []
    gc.disable()
    try:
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
    finally:
        gc.enable()
    return statistics.median(times)


# -- Pinocchio, built from its own joint placements ------------------------------------------------
def pinocchio_model(robot: RobotDescription):
    """Joint i: revolute about z, placed at RotX(alpha) RotY(beta) TransX(a) RotZ(theta_offset)
    TransZ(d) in joint i-1; links point masses at their centres of mass; the tool an operational
    frame of joint 6."""
    import pinocchio as pin

    m = robot.to_modified()

    def rot(axis, angle):
        return pin.AngleAxis(angle, np.eye(3)[axis]).toRotationMatrix()

    model = pin.Model()
    parent = 0
    for i, j in enumerate(m.joints, start=1):
        placement = (
            pin.SE3(rot(0, j.alpha) @ rot(1, j.beta), np.zeros(3))
            * pin.SE3(np.eye(3), np.array([j.a, 0.0, 0.0]))
            * pin.SE3(rot(2, j.theta_offset), np.array([0.0, 0.0, j.d]))
        )
        parent = model.addJoint(parent, pin.JointModelRZ(), placement, f"joint{i}")
        inertia = pin.Inertia(j.mass, np.array(j.com), np.zeros((3, 3)))
        model.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
    tool = pin.SE3(np.eye(3), m.tool_points[0])
    fid = model.addFrame(pin.Frame("tool", parent, 0, tool, pin.FrameType.OP_FRAME))
    model.gravity.linear = np.array(m.gravity)
    return pin, model, fid


def dh_columns(pin, model, robot: RobotDescription, names: tuple[str, ...]) -> np.ndarray:
    """(36, P) map from Pinocchio's joint-placement variations (6 per joint, local, (v, w)) to the
    DH parameters of ``names``. alpha, beta, a perturb the placement on the left (in the parent
    joint's frame), theta_offset and d on the right (both commute with the joint's RotZ)."""
    m = robot.to_modified()
    C = np.zeros((36, len(names)))
    col = {n: k for k, n in enumerate(names)}
    ex, ey, ez, zero = np.eye(3)[0], np.eye(3)[1], np.eye(3)[2], np.zeros(3)
    for i, j in enumerate(m.joints):
        M = model.jointPlacements[i + 1]
        Rx = pin.AngleAxis(j.alpha, ex).toRotationMatrix()
        Rxy = Rx @ pin.AngleAxis(j.beta, ey).toRotationMatrix()
        left = {
            f"dalpha{i + 1}": pin.Motion(zero, ex),
            f"beta{i}": pin.Motion(zero, Rx @ ey),
            f"da{i + 1}": pin.Motion(Rxy @ ex, zero),
        }
        right = {f"dtheta{i + 1}": pin.Motion(zero, ez), f"dd{i + 1}": pin.Motion(ez, zero)}
        for name, xi in left.items():
            if name in col:
                C[6 * i : 6 * i + 6, col[name]] = M.inverse().act(xi).vector
        for name, xi in right.items():
            if name in col:
                C[6 * i : 6 * i + 6, col[name]] = xi.vector
    return C


def pinocchio_fk_variants(pin, model, fid, point):
    data = model.createData()
    fk, ffk, upd = pin.forwardKinematics, pin.framesForwardKinematics, pin.updateFramePlacement
    oMi, oMf = data.oMi, data.oMf

    def act(q):  # forwardKinematics + the tool point through joint 6's placement
        out = np.empty((len(q), 3))
        for k, qk in enumerate(q):
            fk(model, data, qk)
            out[k] = oMi[6].act(point)
        return out

    def frames(q):  # framesForwardKinematics + the tool frame's translation
        out = np.empty((len(q), 3))
        for k, qk in enumerate(q):
            ffk(model, data, qk)
            out[k] = oMf[fid].translation
        return out

    def update(q):  # forwardKinematics + updateFramePlacement of the tool frame only
        out = np.empty((len(q), 3))
        for k, qk in enumerate(q):
            fk(model, data, qk)
            out[k] = upd(model, data, fid).translation
        return out

    return {
        "forwardKinematics + oMi[6].act(tool)": act,
        "framesForwardKinematics + oMf[tool]": frames,
        "forwardKinematics + updateFramePlacement": update,
    }


def pinocchio_identification(pin, model, fid, robot, names, compliance: bool):
    """Per pose: the frame kinematic regressor times the DH map, base and tool columns (the same
    formulas as the model: identity base, tool columns R_6), and compliance columns J_i tau_i."""
    data = model.createData()
    C = dh_columns(pin, model, robot, names)
    geo = [
        k
        for k, n in enumerate(names)
        if n.rstrip("0123456789") in ("dalpha", "da", "dtheta", "dd", "beta")
    ]
    base = [names.index(n) for n in ("bx", "by", "bz", "brx", "bry", "brz")]
    tool = [names.index(n) for n in ("tx", "ty", "tz")]
    comp = [names.index(f"c{i}") for i in range(1, 7)] if compliance else []
    Cg = C[:, geo]
    fk, reg, LWA = (
        pin.forwardKinematics,
        pin.computeFrameKinematicRegressor,
        pin.LOCAL_WORLD_ALIGNED,
    )
    jac, grav = pin.computeFrameJacobian, pin.computeGeneralizedGravity
    oMf = data.oMf

    def run(q):
        # Pinocchio per pose (its calls only); the column algebra batched in numpy afterwards
        n = len(q)
        R = np.empty((n, 3, 36))
        rot = np.empty((n, 3, 3))
        pos = np.empty((n, 3))
        Jq = np.empty((n, 3, 6))
        tau = np.empty((n, 6))
        for k, qk in enumerate(q):
            fk(model, data, qk)
            R[k] = reg(model, data, fid, LWA)[:3]
            M = oMf[fid]
            rot[k], pos[k] = M.rotation, M.translation
            if comp:
                Jq[k] = jac(model, data, qk, fid, LWA)[:3]
                tau[k] = grav(model, data, qk)
        J = np.zeros((n, 3, len(names)))
        J[:, :, geo] = R @ Cg
        J[:, :, base[:3]] = np.eye(3)
        x, y, z = pos.T
        J[:, 0, base[4]], J[:, 0, base[5]] = z, -y  # -[p]x: d(R(r) p)/dr at r = 0
        J[:, 1, base[3]], J[:, 1, base[5]] = -z, x
        J[:, 2, base[3]], J[:, 2, base[4]] = y, -x
        J[:, :, tool] = rot
        if comp:
            J[:, :, comp] = Jq * -tau[:, None, :]
        return J

    return run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats (a smoke run)")
    ap.add_argument("--no-write", action="store_true", help="print, do not write results/")
    args = ap.parse_args()
    k = 0.3 if args.quick else 1.0

    robot = seed_robot()
    chain = Chain.from_description(robot)
    point = robot.tool_points[0]
    rng = np.random.default_rng(0)
    q_all = sample_poses(robot, 100_000, rng)
    pin, model, fid = pinocchio_model(robot)

    # -- forward kinematics ----------------------------------------------------------------------
    variants = pinocchio_fk_variants(pin, model, fid, point)
    probe = q_all[:5000]
    ours_probe = tool_points(chain, probe, point)
    speed = {}
    for name, fn in variants.items():
        err = np.abs(fn(probe) - ours_probe).max()
        assert err < 1e-12, f"Pinocchio ({name}) and sixaxis-track disagree by {err:.3g} m"
        speed[name] = timed(lambda fn=fn: fn(probe), max(2, round(5 * k)))
    best = min(speed, key=speed.get)
    fk_rows = []
    for n in (1_000, 10_000, 100_000):
        q = q_all[:n]
        reps_ours = max(3, round({1_000: 300, 10_000: 60, 100_000: 11}[n] * k))
        reps_pin = max(2, round({1_000: 9, 10_000: 5, 100_000: 3}[n] * k))
        t_ours = timed(lambda q=q: tool_points(chain, q, point), reps_ours)
        t_pin = timed(lambda q=q: variants[best](q), reps_pin)
        fk_rows.append((n, n / t_ours, n / t_pin))
        print(f"FK N={n}: ours {n / t_ours / 1e6:.2f} M/s, Pinocchio {n / t_pin / 1e6:.2f} M/s")

    # -- identification Jacobian -------------------------------------------------------------------
    q = q_all[:1000]
    id_rows = []
    for effects, with_pin in (
        ("geometric", True),
        ("geometric,compliance", True),
        ("geometric,compliance,transmission,joint_scale,backlash,load_backlash,thermal", False),
    ):
        em = ErrorModel(robot, effects)
        cols = {"temperature": np.full(1000, 25.0)} | {
            f"dir{j}": rng.choice((-1.0, 1.0), 1000) for j in range(1, 7)
        }
        inputs = em.inputs(q, cols if "thermal" in effects else None)
        p = em.nominal()
        _, J = em.predict(inputs, p, jacobian=True)
        t_ours = timed(
            lambda em=em, inputs=inputs, p=p: em.predict(inputs, p, jacobian=True),
            max(5, round(200 * k)),
        )
        t_pin = err = None
        if with_pin:
            run = pinocchio_identification(
                pin, model, fid, robot, em.layout.names, "compliance" in effects
            )
            err = float(np.abs(run(q) - J).max())
            assert err < 1e-9, f"Pinocchio's identification columns differ by {err:.3g}"
            t_pin = timed(lambda run=run: run(q), max(2, round(7 * k)))
        id_rows.append((effects, len(em.layout), t_ours, t_pin, err))
        pin_txt = f", Pinocchio {t_pin * 1e3:.2f} ms" if t_pin else ""
        print(f"Jacobian {effects} ({len(em.layout)}): ours {t_ours * 1e3:.2f} ms{pin_txt}")

    # -- report ----------------------------------------------------------------------------------------
    lines = [
        "## Kinematics",
        "",
        f"`python benchmarks/kinematics.py` on {machine()}; numpy {np.__version__}, "
        f"Pinocchio {pin.__version__}. Seed arm (docs/format.md), poses uniform within the limits "
        "with the tool above 0.15 m; medians of repeated runs, both sides in the same run.",
        "",
        "**Tool-point forward kinematics** (poses per second; sixaxis-track: one batched call; "
        f"Pinocchio: a Python loop over poses of `{best}`, the fastest of "
        f"{len(variants)} ways tried; both agree to 1e-12 m):",
        "",
        "| N | sixaxis-track (batched numpy) | Pinocchio (per-pose loop) | ratio |",
        "|---:|---:|---:|---:|",
    ]
    for n, ours, theirs in fk_rows:
        lines.append(
            f"| {n:,} | {ours / 1e6:.2f} M/s | {theirs / 1e6:.2f} M/s | {ours / theirs:.1f}x |"
        )
    lines += [
        "",
        "**Identification Jacobian of 1,000 poses** (`ErrorModel.predict(..., jacobian=True)`: the "
        "points and every column; Pinocchio: per pose `forwardKinematics` + "
        "`computeFrameKinematicRegressor` mapped onto the DH parameters, base and tool columns, and "
        "for compliance `computeFrameJacobian` times `-computeGeneralizedGravity`; the two agree "
        "to the difference shown). Target: under 5 ms for all parameters.",
        "",
        "| effects | parameters | sixaxis-track | Pinocchio | ratio | max difference |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for effects, n_par, t_ours, t_pin, err in id_rows:
        label = (
            "all seven catalogued effects"
            if effects.count(",") > 2
            else effects.replace(",", " + ")
        )
        theirs = f"{t_pin * 1e3:.2f} ms" if t_pin else "n/a"
        ratio = f"{t_pin / t_ours:.1f}x" if t_pin else "n/a"
        diff = f"{err:.1e}" if err is not None else "n/a"
        lines.append(f"| {label} | {n_par} | {t_ours * 1e3:.2f} ms | {theirs} | {ratio} | {diff} |")
    text = "\n".join(lines)
    print()
    print(text)
    if not args.no_write:
        print(f"\nwrote {write_section('kinematics', text)}")


if __name__ == "__main__":
    main()
