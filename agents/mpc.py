"""Kinematic model predictive control of the tool point (CasADi), with online calibration.

Over a horizon of N control steps the controller chooses joint-velocity commands v_0..v_{N-1}
(the decision variables, 6N) so that the *model's* tool point follows the reference preview:

    min  1/2 sum_k |x(q_k) - r_k|^2 (mm^2)  +  rho_dv/2 sum_k |v_k - v_{k-1}|^2  +  rho_v/2 sum_k |v_k|^2
                                             +  rho_q/2 sum_k |q_k - q_posture|^2
    s.t. q_k = q_0 + dt (v_0 + ... + v_{k-1})                      (joint integrators)
         |v_k| <= v_max,  |v_k - v_{k-1}| <= a_max dt,  q_lower + m <= q_k <= q_upper - m

with ``x`` the :class:`~agents.tool_model.ToolModel` of the current model estimate (nominal
description + identified errors + effects), ``q_posture`` the posture at the phase's start (it
holds the three redundant directions of a point task), and ``r_k`` the reference preview plus
``error_decay**k (x(q_0) - r_now)``: the plan removes the present error geometrically (by 70 % a
step by default) rather than at once; a dead-beat correction through the motor encoders pumped
energy into elastic links after a load change and diverged. Two ways to solve it:

* ``solver="daqp" | "osqp" | "qpoases" | "proxqp"`` (default daqp): a QP from the kinematics
  linearised at the current encoder reading, ``x(q_k) ~ x(q_0) + J (q_k - q_0)`` with ``J`` the
  model's d x / d q (CasADi's derivative of the full model), condensed onto the velocities. The
  constraint matrix is constant, only the Hessian (through ``J``), the gradient and the bounds
  change; the solution is warm-started from the previous plan shifted by one step (OSQP and
  qpOASES use it; DAQP, a dual active-set method, starts cold through CasADi). The QP is re-solved
  at every step from the new encoder reading, so the linearisation error of one step is corrected
  at the next.
* ``solver="ipopt"``: the full nonlinear program with the exact model at every q_k, warm-started
  from the previous primal-dual solution.

:class:`MPCAgent` wires it to the environment and to :class:`~agents.online_calibration.
RecursiveLeastSquares`, which updates the model from tracker measurements (``"mpc"``), or hands it
the plant's true model (``"mpc-oracle"``, the floor that model knowledge can reach).

It is one module, longer than most, because the condensed QP, its solvers and the agent that feeds
it the calibrated model share the horizon's layout.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from agents.base import Agent, measurement_columns, refuse_settings, solve_time_stats
from agents.errors import AgentError
from agents.online_calibration import (
    ESTIMATOR_SETTINGS,
    MeasurementBuffer,
    RecursiveLeastSquares,
    cached_identifiable,
    merge_effects,
)
from agents.tool_model import BufferedFunction, ToolModel, cached_tool_model
from arm.constraints import Constraint, Interval, OneOf
from arm.errormodel import ErrorModel
from envs.task import Observation, TaskInfo, Truth

__all__ = ["QP_SOLVERS", "KinematicMPC", "MPCAgent", "Widening"]

log = logging.getLogger(__name__)

QP_SOLVERS = ("daqp", "osqp", "qpoases", "proxqp")
#: what the MPC's settings may be (:mod:`arm.constraints`): its solver, the steps it plans
#: ahead, the decay per step of the measured error it carries forward, the points it keeps
MPC_SETTINGS: dict[str, Constraint] = {
    "solver": OneOf((*QP_SOLVERS, "ipopt")),
    "horizon": Interval(int, 1, None),
    "error_decay": Interval(float, 0.0, 1.0, closed="left"),
    "buffer": Interval(int, 0, None),
}
MM = 1e3  # the cost is in mm: tracking errors of 0.01-1 mm give well-scaled QPs


def _qp_options(solver: str) -> dict:
    if solver == "osqp":
        return {
            "osqp": {
                "verbose": False,
                "eps_abs": 1e-7,
                "eps_rel": 1e-7,
                "polish": False,  # prints even when not verbose
                "max_iter": 4000,
            },
            "warm_start_primal": True,
            "warm_start_dual": True,
            "error_on_fail": False,
        }
    if solver == "qpoases":
        return {"printLevel": "none", "sparse": False, "error_on_fail": False}
    return {"error_on_fail": False}


class KinematicMPC:
    """The optimal-control problem of the module docstring for one arm and one model.

    ``solve(q0, v_prev, refs, p, columns)`` returns the first command v_0 (rad/s); the whole plan
    is in ``plan`` (N, 6). ``refs`` (N, 3) are the reference points at t + dt .. t + N dt.
    """

    def __init__(
        self,
        tool_model: ToolModel,
        dt: float,
        v_max: np.ndarray,
        a_max: np.ndarray,
        q_lower: np.ndarray,
        q_upper: np.ndarray,
        horizon: int = 10,
        solver: str = "daqp",
        rho_dv: float = 1e-2,
        rho_v: float = 1e-3,
        rho_q: float = 1e-1,
        error_decay: float = 0.3,
        limit_margin: float = 0.02,
        velocity_margin: float = 0.98,
        fast: bool = True,
    ) -> None:
        refuse_settings(MPC_SETTINGS, solver=solver, horizon=horizon, error_decay=error_decay)
        self.tm = tool_model
        self.dt = float(dt)
        self.v_max = np.asarray(v_max, dtype=float) * velocity_margin
        self.a_max = np.asarray(a_max, dtype=float)
        self.q_lower = np.asarray(q_lower, dtype=float) + limit_margin
        self.q_upper = np.asarray(q_upper, dtype=float) - limit_margin
        self.N = int(horizon)
        self.solver = solver
        self.rho_dv = float(rho_dv)
        self.rho_v = float(rho_v)
        self.rho_q = float(rho_q)
        self.error_decay = float(error_decay)
        N = self.N
        I6 = np.eye(6)
        # D: v_k - v_{k-1}; L: dt * sum_{j<=k} v_j; both constant
        Dn = np.eye(N) - np.eye(N, k=-1)
        self.A = np.vstack([np.kron(Dn, I6), np.kron(np.tril(np.ones((N, N))), I6) * self.dt])
        self.nA = self.A.shape[0]
        self._C = (N - np.maximum.outer(np.arange(N), np.arange(N))).astype(float)
        self._R = (
            self.rho_dv * np.kron(Dn.T @ Dn, I6)
            + self.rho_v * np.eye(6 * N)
            + self.rho_q * self.dt**2 * np.kron(self._C, I6)
        )
        self._decay = self.error_decay ** np.arange(1, N + 1)  # of the present error, by step
        self._lbx = -np.tile(self.v_max, N)
        self._ubx = np.tile(self.v_max, N)
        self._warm_start = solver in ("osqp", "qpoases", "ipopt")
        # a plan violating the constraints by more than this (rad/s) is a failed solve: active-set
        # methods are exact; first-order ones (OSQP's ADMM) stop near the solution, or at their
        # iteration limit on hard problems, and the servo clips what little is left
        self._tolerance = 1e-3 if solver in ("osqp", "proxqp") else 1e-6
        self.n_fail = 0
        self.n_constrained = 0  # QP steps on which a constraint bound (the solver ran)
        self.last_status = ""
        self.reset()
        self._fast: BufferedFunction | None = None
        if solver == "ipopt":
            self._build_nlp()
        else:
            self._build_qp()
            if fast:
                self._build_fast()

    def reset(self) -> None:
        self.plan = np.zeros((self.N, 6))
        self._lam_x = np.zeros(6 * self.N)
        self._lam_a = np.zeros(self.nA)

    def _warm(self) -> np.ndarray:
        return np.concatenate([self.plan[1:].reshape(-1), self.plan[-1]])

    # -- bounds ----------------------------------------------------------------------------------
    def constraint_bounds(self, q0: np.ndarray, v_prev: np.ndarray):
        """Bounds (lba, uba) of the rows of ``A``: acceleration, then joint position."""
        N = self.N
        da = self.a_max * self.dt
        lb = np.empty((2, N, 6))
        ub = np.empty((2, N, 6))
        lb[0] = -da
        ub[0] = da
        lb[0, 0] += v_prev
        ub[0, 0] += v_prev
        # joint limits; where q0 is already beyond a limit, only forbid going further
        lb[1] = np.minimum(self.q_lower - q0, 0.0)
        ub[1] = np.maximum(self.q_upper - q0, 0.0)
        return lb.reshape(-1), ub.reshape(-1)

    def _symbolic_bounds(self, q0, v_prev):
        N = self.N
        da = ca.DM(self.a_max * self.dt)
        lo = ca.fmin(ca.DM(self.q_lower) - q0, 0)
        hi = ca.fmax(ca.DM(self.q_upper) - q0, 0)
        lba = ca.vertcat(v_prev - da, ca.repmat(-da, N - 1, 1), ca.repmat(lo, N, 1))
        uba = ca.vertcat(v_prev + da, ca.repmat(da, N - 1, 1), ca.repmat(hi, N, 1))
        return lba, uba

    # -- the QP ----------------------------------------------------------------------------------
    def qp_matrices(
        self,
        x0: np.ndarray,
        J: np.ndarray,
        refs: np.ndarray,
        v_prev: np.ndarray,
        q0: np.ndarray | None = None,
        q_posture: np.ndarray | None = None,
        r0: np.ndarray | None = None,
    ):
        """Hessian (6N, 6N) and gradient (6N,) of the condensed QP at point x0 with d x / d q J
        (numpy, for reading and testing; the compiled step computes the same inside CasADi)."""
        dt = self.dt
        Jm = J * MM
        E = (x0[None, :] - refs) * MM  # (N, 3) errors if nothing moved
        if r0 is not None:
            E -= np.outer(self._decay, x0 - r0) * MM
        S = np.cumsum(E[::-1], axis=0)[::-1]  # S_j = sum_{k >= j} E_k
        H = dt * dt * np.kron(self._C, Jm.T @ Jm) + self._R
        g = dt * (S @ Jm).reshape(-1)
        g[:6] -= self.rho_dv * v_prev
        if q0 is not None and q_posture is not None:
            counts = self.N - np.arange(self.N)
            g += self.rho_q * dt * np.kron(counts, np.asarray(q0) - np.asarray(q_posture))
        return H, g

    def _qp_data(self) -> tuple[Any, Any, Any, Any, tuple[Any, ...]]:
        """The condensed QP's Hessian, gradient and constraint bounds as scalar expressions (SX)
        of the step's inputs ``(z, refs, v_prev, q_posture, r0)``: the model's point and
        d x / d q at ``q0`` (``z``: encoders, parameters, columns), the references, the previous
        command, the posture and the reference now."""
        N, dt, tm = self.N, self.dt, self.tm
        z = ca.SX.sym("z", tm.n_inputs)
        refs = ca.SX.sym("refs", 3 * N)
        v_prev = ca.SX.sym("v_prev", 6)
        q_post = ca.SX.sym("q_posture", 6)
        r0 = ca.SX.sym("r0", 3)
        q0 = z[:6]
        P, nc = len(tm.layout), len(tm.column_names)
        x = tm.expression(q0, z[6 : 6 + P], z[6 + P : 6 + P + nc], z[6 + P + nc :])
        Jm = ca.jacobian(x, q0) * MM
        E = (ca.repmat(x, 1, N) - ca.reshape(refs, 3, N)) * MM  # (3, N)
        E = E - ca.mtimes(x - r0, ca.DM(self._decay).T) * MM
        # S_j = sum_{k >= j} E_k (E_k the error at step k + 1), a constant lower-triangular product
        S = ca.mtimes(E, ca.DM(np.tril(np.ones((N, N)))))
        H = dt * dt * ca.kron(ca.DM(self._C), ca.mtimes(Jm.T, Jm)) + ca.DM(self._R)
        g = dt * ca.vec(ca.mtimes(Jm.T, S))
        g = g - ca.vertcat(self.rho_dv * v_prev, ca.DM.zeros(6 * (N - 1)))
        counts = ca.DM(N - np.arange(N))
        g = g + self.rho_q * dt * ca.kron(counts, q0 - q_post)
        lba, uba = self._symbolic_bounds(q0, v_prev)
        return H, g, lba, uba, (z, refs, v_prev, q_post, r0)

    def _build_qp(self) -> None:
        """One CasADi function per step: the model's point and d x / d q at q0, the condensed QP's
        Hessian, gradient and bounds, and the QP solver on them. Its input and output are single
        vectors: no matrix crosses into Python."""
        N, nA = self.N, self.nA
        nz = self.tm.n_inputs
        A = ca.sparsify(ca.DM(self.A))  # block bidiagonal and block lower-triangular
        qp = {"h": ca.Sparsity.dense(6 * N, 6 * N), "a": A.sparsity()}
        self._qp = ca.conic("mpc_qp", self.solver, qp, _qp_options(self.solver))
        # the QP's data as an SX function (scalar expressions, fast to evaluate) ...
        H, g, lba, uba, inputs = self._qp_data()
        data = ca.Function("mpc_qp_data", list(inputs), [H, g, lba, uba])
        # ... and the solver called on it, in an MX function
        n_in = nz + 3 * N + 15
        w = ca.MX.sym("w", n_in + (12 * N + nA if self._warm_start else 0))
        o = nz + 3 * N
        Hw, gw, lbaw, ubaw = data(
            w[:nz], w[nz:o], w[o : o + 6], w[o + 6 : o + 12], w[o + 12 : n_in]
        )
        args: dict[str, ca.MX | ca.DM] = {
            "h": Hw,
            "g": gw,
            "a": A,
            "lba": lbaw,
            "uba": ubaw,
            "lbx": ca.DM(self._lbx),
            "ubx": ca.DM(self._ubx),
        }
        if self._warm_start:
            args |= {
                "x0": w[n_in : n_in + 6 * N],
                "lam_x0": w[n_in + 6 * N : n_in + 12 * N],
                "lam_a0": w[n_in + 12 * N :],
            }
        sol = self._qp(**args)
        v = sol["x"]
        Av = ca.mtimes(A, v)
        violation = ca.mmax(
            ca.vertcat(Av - ubaw, lbaw - Av, v - ca.DM(self._ubx), ca.DM(self._lbx) - v)
        )
        out = [v, violation]
        if self._warm_start:
            out += [sol["lam_x"], sol["lam_a"]]
        self._step = ca.Function("mpc_qp_step", [w], [ca.vertcat(*out)])

    def _build_fast(self) -> None:
        """The QP's unconstrained minimiser ``-H^-1 g`` by a factorisation of the Hessian
        (CasADi's own sparse LDL': no BLAS, whose threads would round differently from one
        process to the next), and how far it violates the constraints, in one compiled function
        called through its own buffers. When no constraint binds this *is* the QP's solution (the
        problem is convex), and it is what the tracking steps almost always are: the solver runs
        only when the minimiser violates a bound (a few steps of an episode, at the first
        corrections).

        Not a structured closed form: one (the Hessian's Kronecker form split by the generalised
        eigenvectors of its constant part) took a few thousand scalar operations instead of a
        60 x 60 factorisation, but cancelled two terms of the size of the tracking error's
        gradient, carried a rounding difference of the encoders a thousand times further than a
        factorisation does, and the MPC's rows then moved by up to 1e-5 on another CPU
        (``benchmarks/perturbation.py``)."""
        H, g, lba, uba, inputs = self._qp_data()
        data = ca.Function("mpc_qp_data", list(inputs), [H, g, lba, uba])
        sizes = [int(x.numel()) for x in inputs]
        w = ca.MX.sym("w", sum(sizes))
        parts = ca.vertsplit(w, list(np.cumsum([0, *sizes])))
        Hw, gw, lbaw, ubaw = data(*parts)
        v = -ca.solve(Hw, gw, "ldl")
        Av = ca.mtimes(ca.DM(self.A), v)
        violation = ca.mmax(
            ca.vertcat(Av - ubaw, lbaw - Av, v - ca.DM(self._ubx), ca.DM(self._lbx) - v)
        )
        f = ca.Function("mpc_unconstrained", [w], [ca.densify(ca.vertcat(v, violation))])
        self._fast = BufferedFunction(f)

    def solve(
        self,
        q0: np.ndarray,
        v_prev: np.ndarray,
        refs: np.ndarray,
        p: np.ndarray,
        columns: Mapping[str, float] | np.ndarray | None = None,
        q_posture: np.ndarray | None = None,
        ref_now: np.ndarray | None = None,
    ) -> np.ndarray:
        """The first command v_0 (rad/s) of the plan from encoder reading ``q0``, previous command
        ``v_prev``, references ``refs`` (N, 3) and model parameters ``p`` (with ``columns``);
        ``q_posture`` (default ``q0``) the posture that the redundant directions keep to;
        ``ref_now`` the reference at this instant (default ``refs[0]``): the plan removes the
        model's present error ``x(q0) - ref_now`` along ``error_decay**k``, not in one step."""
        v_prev = np.clip(np.asarray(v_prev, dtype=float), -self.v_max, self.v_max)
        refs = np.asarray(refs, dtype=float).reshape(self.N, 3)
        z = self.tm.pack(q0, p, columns)
        qp_ = z[:6] if q_posture is None else np.asarray(q_posture, dtype=float).reshape(6)
        r0 = refs[0] if ref_now is None else np.asarray(ref_now, dtype=float).reshape(3)
        if self.solver == "ipopt":
            return self._solve_nlp(z, v_prev, refs, qp_, r0)
        parts = [z, refs.reshape(-1), v_prev, qp_, r0]
        n = 6 * self.N
        if self._fast is not None:
            out = self._fast(np.concatenate(parts))
            if out[n] <= 0.0:  # no constraint binds (NaN does not pass)
                self.last_status = "ok"
                if self._warm_start:
                    self._lam_x[:] = 0.0
                    self._lam_a[:] = 0.0
                return self._accept(True, out[:n].copy(), v_prev)
            self.n_constrained += 1
        if self._warm_start:
            parts += [self._warm(), self._lam_x, self._lam_a]
        out = self._step(np.concatenate(parts)).full().reshape(-1)
        v, violation = out[:n], out[n]
        ok = bool(np.all(np.isfinite(v)) and violation < self._tolerance)
        self.last_status = "ok" if ok else f"failed (constraint violation {violation:.3g})"
        if ok and self._warm_start:
            self._lam_x = out[n + 1 : 2 * n + 1]
            self._lam_a = out[2 * n + 1 :]
        return self._accept(ok, v, v_prev)

    def _accept(self, ok: bool, v: np.ndarray, v_prev: np.ndarray) -> np.ndarray:
        if ok:
            self.plan = v.reshape(self.N, 6)
            return self.plan[0].copy()
        # no solution: brake within the acceleration limit (always feasible)
        self.n_fail += 1
        log.debug("MPC solve failed (%s); braking", self.last_status)
        da = self.a_max * self.dt
        v0 = v_prev - np.clip(v_prev, -da, da)
        self.plan = np.repeat(v0[None, :], self.N, axis=0)
        self._lam_x[:] = 0.0
        self._lam_a[:] = 0.0
        return v0

    # -- the NLP ---------------------------------------------------------------------------------
    def _build_nlp(self) -> None:
        N, dt = self.N, self.dt
        tm = self.tm
        P, nc = len(tm.layout), len(tm.column_names)
        V = ca.SX.sym("v", 6 * N)
        z = ca.SX.sym("z", tm.n_inputs)
        refs = ca.SX.sym("refs", 3 * N)
        v_prev = ca.SX.sym("v_prev", 6)
        q_post = ca.SX.sym("q_posture", 6)
        r0 = ca.SX.sym("r0", 3)
        q0, p, c, off = z[:6], z[6 : 6 + P], z[6 + P : 6 + P + nc], z[6 + P + nc :]
        qs, ps, cs, os_ = (
            ca.SX.sym("q", 6),
            ca.SX.sym("p", P),
            ca.SX.sym("c", nc),
            ca.SX.sym("o", 6),
        )
        f = ca.Function("x", [qs, ps, cs, os_], [tm.expression(qs, ps, cs, os_)])
        cost = 0
        q = q0
        e0 = f(q0, p, c, off) - r0
        for k in range(N):
            vk = V[6 * k : 6 * k + 6]
            q = q + dt * vk
            e = (f(q, p, c, off) - refs[3 * k : 3 * k + 3] - self._decay[k] * e0) * MM
            cost += 0.5 * ca.dot(e, e)
            prev = v_prev if k == 0 else V[6 * k - 6 : 6 * k]
            cost += 0.5 * self.rho_dv * ca.sumsqr(vk - prev) + 0.5 * self.rho_v * ca.sumsqr(vk)
            cost += 0.5 * self.rho_q * ca.sumsqr(q - q_post)
        g = ca.mtimes(ca.DM(self.A), V)
        nlp: dict[str, ca.SX | float] = {
            "x": V,
            "p": ca.vertcat(z, refs, v_prev, q_post, r0),
            "f": cost,
            "g": g,
        }
        opts: dict[str, Any] = {
            "ipopt": {
                "print_level": 0,
                "sb": "yes",
                "tol": 1e-8,
                "max_iter": 100,
                "warm_start_init_point": "yes",
                "mu_init": 1e-3,
            },
            "print_time": False,
            "error_on_fail": False,
        }
        self._nlp = ca.nlpsol("mpc_nlp", "ipopt", nlp, opts)

    def _solve_nlp(self, z, v_prev, refs, q_posture, r0) -> np.ndarray:
        lbg, ubg = self.constraint_bounds(z[:6], v_prev)
        sol = self._nlp(
            x0=self._warm(),
            p=np.concatenate([z, refs.reshape(-1), v_prev, q_posture, r0]),
            lbx=self._lbx,
            ubx=self._ubx,
            lbg=lbg,
            ubg=ubg,
            lam_x0=self._lam_x,
            lam_g0=self._lam_a,
        )
        stats = self._nlp.stats()
        self.last_status = str(stats.get("return_status", ""))
        ok = bool(stats.get("success", False)) or self.last_status == "Solved_To_Acceptable_Level"
        v = sol["x"].full().reshape(-1)
        ok = ok and bool(np.all(np.isfinite(v)))
        if ok:
            self._lam_x = sol["lam_x"].full().reshape(-1)
            self._lam_a = sol["lam_g"].full().reshape(-1)
        return self._accept(ok, v, v_prev)


@dataclass(frozen=True)
class Widening:
    """What :meth:`MPCAgent.prepare_widening` built: the wider model, its tool model, the MPC on
    it and the estimator's free parameters (None without an estimator)."""

    model: ErrorModel
    tool_model: ToolModel
    mpc: KinematicMPC
    free: list[str] | None

    @property
    def tm(self) -> ToolModel:
        return self.tool_model


class MPCAgent(Agent):
    """Kinematic MPC on a model that online least squares keeps calibrated.

    Settings: ``solver`` (daqp, osqp, qpoases, proxqp, ipopt), ``horizon`` (steps), ``effects``
    (what the model and the estimator can express), ``online`` (estimate from measurements),
    ``oracle`` (use the plant's true model; needs ``truth``), ``forgetting`` and ``sigma`` (m, default
    the task's instrument noise) of the estimator, ``free`` (names to estimate; default the
    identifiable ones), the cost weights ``rho_dv``, ``rho_v``, ``rho_q`` (posture: the
    redundant directions keep to the posture of the phase's start), ``buffer`` (how many
    tracker points to keep with their inputs, :class:`~agents.online_calibration.
    MeasurementBuffer`; 0: none) and ``closed_form`` (False: the QP solver on every step, not only
    when the closed-form step violates a bound; for comparison).

    :meth:`widen` adds effects during an episode: the model, the MPC and the estimator continue
    with them, keeping what the estimator learned.
    """

    name = "mpc"

    def __init__(
        self,
        solver: str = "daqp",
        horizon: int = 10,
        effects: str | Sequence[str] = "geometric",
        online: bool = True,
        oracle: bool = False,
        forgetting: float = 0.995,
        sigma: float | None = None,
        free: Sequence[str] | None = None,
        rho_dv: float = 1e-2,
        rho_v: float = 1e-3,
        rho_q: float = 1e-1,
        error_decay: float = 0.3,
        buffer: int = 0,
        closed_form: bool = True,
        name: str | None = None,
    ) -> None:
        super().__init__()
        self.closed_form = bool(closed_form)
        refuse_settings(  # all at once, when the agent is made (a config is checked by it)
            MPC_SETTINGS | ESTIMATOR_SETTINGS,
            solver=solver,
            horizon=horizon,
            error_decay=error_decay,
            buffer=buffer,
            forgetting=forgetting,
            sigma=sigma,
        )
        self.buffer_points = int(buffer)
        self.buffer: MeasurementBuffer | None = None
        self.solver = solver
        self.horizon = int(horizon)
        self.effects = effects
        self.online = bool(online) and not oracle
        self.oracle = bool(oracle)
        self.needs_truth = self.oracle
        self.forgetting = float(forgetting)
        self.sigma = sigma
        self.free = None if free is None else list(free)
        self.rho_dv, self.rho_v, self.rho_q = float(rho_dv), float(rho_v), float(rho_q)
        self.error_decay = float(error_decay)
        if name:
            self.name = name
        elif oracle:
            self.name = "mpc-oracle"
        elif solver == "ipopt":
            self.name = "mpc-ipopt"
        self.rls: RecursiveLeastSquares | None = None
        self.model: ErrorModel | None = None
        self.p: np.ndarray | None = None
        self.truth: Truth | None = None  # oracles only

    # -- episode ---------------------------------------------------------------------------------
    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task = task
        self.truth = truth
        if self.oracle:
            if truth is None:
                raise AgentError("mpc-oracle needs the plant's truth (env.unwrapped.truth)")
            self.model = truth.model
            self.p = np.array(truth.params, dtype=float)
        else:
            self.model = ErrorModel(task.robot, self.effects)
            self.p = self.model.nominal()
        tm = cached_tool_model(self.model)
        self.mpc = self._make_mpc(tm)
        self.tm = tm
        self.buffer = MeasurementBuffer(self.buffer_points) if self.buffer_points else None
        if self.online:
            noise = task.noise_mm
            sigma = self.sigma if self.sigma is not None else max(noise * 1e-3, 2e-6)
            self.rls = RecursiveLeastSquares(
                self.model,
                free=self.free if self.free is not None else cached_identifiable(self.model),
                sigma=sigma,
                forgetting=self.forgetting,
                tool_model=tm,
            )
            self.p = self.rls.params
        self._times: list[float] = []
        self._update_times: list[float] = []
        self._start_phase()

    def _make_mpc(self, tm: ToolModel) -> KinematicMPC:
        task = self.task
        return KinematicMPC(
            tm,
            task.dt,
            task.v_max,
            task.a_max,
            task.q_lower,
            task.q_upper,
            horizon=self.horizon,
            solver=self.solver,
            rho_dv=self.rho_dv,
            rho_v=self.rho_v,
            rho_q=self.rho_q,
            error_decay=self.error_decay,
            fast=self.closed_form,
        )

    def next_phase(self, task: TaskInfo, truth: Truth | None = None) -> None:
        self.task = task
        self.truth = truth
        self._start_phase()

    # -- widening ----------------------------------------------------------------------------------
    def prepare_widening(self, effects: str | Sequence[str]) -> Widening:
        """Everything :meth:`widen` builds, without touching the running controller: the model
        with ``effects`` added to the current ones (joints of a per-joint effect merged), its
        CasADi tool model, the MPC on it, the estimator's free parameters and its compiled
        update. The CasADi builds take a fraction of a second (once per process for each effect
        set); a controller that must keep its deadlines builds this off the control path (a
        thread) and hands it to :meth:`adopt_widening`."""
        if self.model is None or self.oracle:
            raise AgentError("widen needs a running, non-oracle MPCAgent (call reset first)")
        model = ErrorModel(
            self.model.robot, merge_effects(self.model, effects), targets=self.model.targets
        )
        tm = cached_tool_model(model)
        mpc = self._make_mpc(tm)
        free = None
        if self.rls is not None:
            free = self.rls.widened_free(model)
            self.rls.prepare_widening(model, free, tm)
        return Widening(model, tm, mpc, free)

    def adopt_widening(self, w: Widening) -> list[str]:
        """Continue with a prepared :class:`Widening`; returns the parameters added to the
        estimator. Takes milliseconds: the plan in progress carries over."""
        added: list[str] = []
        old = self.model
        assert old is not None and self.p is not None
        w.mpc.plan = self.mpc.plan.copy()
        w.mpc.n_fail, w.mpc.n_constrained = self.mpc.n_fail, self.mpc.n_constrained
        if self.rls is not None:
            added = self.rls.widen(w.model, w.free, tool_model=w.tm)
            p = self.rls.params
        else:
            p = w.model.nominal()
            p[w.model.layout.indices(list(old.layout.names))] = self.p
        self.model, self.tm, self.mpc, self.p = w.model, w.tm, w.mpc, p
        return added

    def widen(self, effects: str | Sequence[str]) -> list[str]:
        """Add ``effects`` (e.g. ``"backlash[1,5]"`` or a diagnosis's suggestion
        ``"geometric,backlash[1,5]"``) to the model during an episode; returns the parameters
        the estimator added. What the estimator learned is kept
        (:meth:`~agents.online_calibration.RecursiveLeastSquares.widen`)."""
        return self.adopt_widening(self.prepare_widening(effects))

    def _start_phase(self) -> None:
        assert self.model is not None, "reset() makes the model"
        self.v_prev = np.zeros(6)
        self.dirs = np.zeros(6)
        self.payload = float(self.model.robot.payload)
        self._last_meas_time = None
        self.q_posture: np.ndarray | None = None
        self.mpc.reset()

    # -- step -------------------------------------------------------------------------------------
    def _update_model(self, info: Mapping[str, Any]) -> None:
        cols = measurement_columns(info)
        if "payload" in cols and np.isfinite(cols["payload"]):
            self.payload = cols["payload"]
        rls = self.rls
        if rls is None or not info.get("measurement_valid", False):
            return
        t_meas = info.get("measurement_time")
        if t_meas is not None and t_meas == self._last_meas_time:
            return  # the same measurement again
        self._last_meas_time = t_meas
        y = info.get("measurement")
        q_meas = info.get("measurement_q")
        if y is None or q_meas is None:
            return
        accepted = rls.update(q_meas, y, cols)
        if accepted:
            self.p = rls.params
        if self.buffer is not None:
            self.buffer.append(q_meas, y, cols, accepted)

    def _columns(self, o: Observation) -> np.ndarray:
        if self.oracle and self.truth is not None:  # the plant's exact conditions, not sensors
            cols = dict(self.truth.conditions())
        else:
            if o.payload is not None:
                self.payload = o.payload
            cols = {"temperature": o.temperature, "payload": self.payload}
        cols.update({f"dir{i + 1}": float(self.dirs[i]) for i in range(6)})
        return self.tm.column_vector(cols)

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        t0 = time.perf_counter()
        o = Observation.parse(self.task, obs)
        self._update_model(info)
        t1 = time.perf_counter()
        refs = o.references(self.horizon)
        if self.q_posture is None:  # the posture of the phase's start
            self.q_posture = np.array(o.q, dtype=float)
        assert self.p is not None, "reset() sets the parameters"
        v = self.mpc.solve(o.q, self.v_prev, refs, self.p, self._columns(o), self.q_posture, o.ref)
        moving = np.abs(v) > 1e-6
        self.dirs[moving] = np.sign(v[moving])
        self.v_prev = v
        t2 = time.perf_counter()
        self.last_solve_time = t2 - t0
        self._times.append(t2 - t0)
        self._update_times.append(t1 - t0)
        return np.clip(v / np.asarray(self.task.v_max, dtype=float), -1.0, 1.0)

    def report(self) -> dict[str, float | list]:
        out: dict[str, float | list] = {"mpc_failures": self.mpc.n_fail}
        out |= solve_time_stats(self._times)
        out |= solve_time_stats(self._update_times, "model_update_time")
        if self.rls is not None:
            out |= self.rls.report()
        if self.model is not None and self.p is not None:
            out["parameter_names"] = list(self.model.layout.names)
            out["parameters"] = [float(v) for v in self.p]
        return out
