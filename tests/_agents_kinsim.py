"""A small pure-numpy kinematic stand-in for SixAxisTrack-v0, for the agents' fast tests.

Same contract as the real env (spaces, the real ``task`` and ``truth`` classes, observation slices,
info keys), but the plant is the error model itself: an ideal velocity servo (acceleration-limited
integrator) and the tool point of the true parameters. It isolates the controllers and the estimator from the MuJoCo
physics, so their tests check the algorithms: with a perfect servo the MPC's oracle error is
nearly zero and a calibrated model must get close to it.
"""

from __future__ import annotations

from dataclasses import replace

import gymnasium as gym
import numpy as np

from arm.description import seed_robot
from arm.errormodel import ErrorModel
from arm.sampling import sample_parameters
from envs.plant import HiddenEffects
from envs.scenarios import EpisodeTruth
from envs.task import TaskInfo

KIN_ENV_ID = "SixAxisKinematic-v0"


SCENARIO_EFFECTS = {
    "nominal": "geometric",
    "geometric": "geometric",
    "compliance": "geometric,compliance",
}
Q_START = np.array([0.2, -1.3, 0.5, 0.3, -0.6, 0.4])


class KinematicTrackEnv(gym.Env):
    metadata = {"render_modes": []}

    def __init__(
        self,
        scenario="geometric",
        trajectory="circle",
        noise_mm=0.015,
        measure_every=5,
        dropout=0.0,
        latency_steps=0,
        measurements=True,
        preview_steps=10,
        outliers=0.0,
        payload=2.0,
    ):
        self.robot = replace(seed_robot(), payload=payload)
        self.scenario = scenario
        self.trajectory = trajectory
        self.noise = noise_mm * 1e-3
        self.measure_every = measure_every
        self.dropout = dropout
        self.latency = latency_steps
        self.measurements = measurements
        self.P = preview_steps
        self.outliers = outliers
        self.dt = 0.02
        names = ["q", "qd", "ref", "preview", "meas", "meas_age", "meas_valid", "temperature"]
        sizes = [6, 6, 3, 3 * self.P, 3, 1, 1, 1]
        sl, k = {}, 0
        for n, s in zip(names, sizes, strict=True):
            sl[n] = slice(k, k + s)
            k += s
        self.task = TaskInfo(
            robot=self.robot,
            dt=self.dt,
            v_max=np.array([2.0, 2.0, 2.0, 3.0, 3.0, 4.0]),
            a_max=np.array([8.0, 8.0, 8.0, 12.0, 12.0, 15.0]),
            q_lower=self.robot.lower,
            q_upper=self.robot.upper,
            preview_steps=self.P,
            obs_slices=sl,
            noise_mm=noise_mm,
            measure_every=measure_every,
            latency_steps=latency_steps,
            dropout=dropout,
            measurements=measurements,
            temperature_noise=0.0,  # the kinematic stand-in's temperature is exact and constant
            temperature_lag=0.0,
            physics_dt=self.dt,  # the servo is integrated once per control step
            substeps=1,
            torque_max=np.full(6, np.inf),  # an ideal servo
            jerk_weight=0.0,
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, (6,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (k,), np.float32)

    # reference trajectory around the start point
    def _ref(self, t):
        c, r, w = self.center, 0.08, 2 * np.pi / 5.0
        if self.trajectory == "circle":
            return c + r * np.array([np.cos(w * t) - 1, np.sin(w * t), 0.0])
        if self.trajectory == "lemniscate":
            s = np.sin(w * t)
            return c + np.array([0.0, 1.5 * r * s, 1.5 * r * s * np.cos(w * t)])
        if self.trajectory == "wide":  # a large, slow excursion for calibration
            return c + np.array(
                [0.15 * np.sin(0.9 * t), 0.35 * np.sin(0.6 * t), 0.2 * (np.cos(0.7 * t) - 1)]
            )
        raise ValueError(self.trajectory)

    def _true_point(self, q, dirs=None):
        cols = {"payload": np.array([self.robot.payload])}
        return self.truth.model.predict(self.truth.model.inputs(q[None], cols), self.truth.params)[
            0
        ]

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        rng = np.random.default_rng(seed)
        model = ErrorModel(self.robot, SCENARIO_EFFECTS[self.scenario])
        p = model.nominal() if self.scenario == "nominal" else sample_parameters(model, rng)
        # no hidden physics: the plant is the error model itself
        self.truth = EpisodeTruth(self.scenario, model.description(p), model, p, HiddenEffects())
        self.noise_rng = np.random.default_rng([int(seed or 0), 7])
        self.q = Q_START.copy()
        nominal = ErrorModel(self.robot, "geometric")
        self.center = nominal.predict(nominal.inputs(self.q[None]), nominal.nominal())[0]
        self.v = np.zeros(6)
        self.k = 0
        self.history = [self.q.copy()]
        self.meas = np.full(3, np.nan)
        self.meas_time = -np.inf
        return self._obs(), self._info(None)

    def _obs(self):
        t = self.k * self.dt
        pv = np.concatenate([self._ref(t + (i + 1) * self.dt) for i in range(self.P)])
        return np.concatenate(
            [
                self.q,
                self.v,
                self._ref(t),
                pv,
                np.nan_to_num(self.meas),
                [min(t - self.meas_time, 1e3)],
                [float(np.isfinite(self.meas[0]))],
                [20.0],
            ]
        ).astype(np.float32)

    def _info(self, new):
        t = self.k * self.dt
        x = self._true_point(self.q)
        info = {
            "true_error_mm": float(np.linalg.norm(x - self._ref(t)) * 1e3),
            "true_tool": x,
            "reference": self._ref(t),
            "measurement_valid": new is not None,
            "measurement": np.full(3, np.nan) if new is None else new[0],
            "measurement_q": np.full(6, np.nan) if new is None else new[1],
            "measurement_time": np.nan if new is None else new[2],
            "measurement_columns": {"temperature": 20.0, "payload": self.robot.payload},
            "diverged": False,
            "time": t,
        }
        return info

    def step(self, action):
        a = np.asarray(action, dtype=float)
        if a.shape != (6,) or not np.all(np.isfinite(a)):
            raise ValueError(f"bad action {a}")
        v_cmd = np.clip(a, -1, 1) * self.task.v_max
        dv = np.clip(v_cmd - self.v, -self.task.a_max * self.dt, self.task.a_max * self.dt)
        self.v = self.v + dv
        self.q = self.q + self.dt * self.v
        self.k += 1
        self.history.append(self.q.copy())
        new = None
        if self.measurements and self.k % self.measure_every == 0:
            if self.noise_rng.uniform() >= self.dropout:
                ks = max(self.k - self.latency, 0)
                qs = self.history[ks]
                y = self._true_point(qs) + self.noise_rng.normal(0, self.noise, 3)
                if self.noise_rng.uniform() < self.outliers:
                    y = y + self.noise_rng.normal(0, 1e-3, 3)
                new = (y, qs.copy(), ks * self.dt)
                self.meas = y
                self.meas_time = ks * self.dt
        info = self._info(new)
        return self._obs(), -info["true_error_mm"], False, False, info


def register_kinematic_env() -> str:
    if KIN_ENV_ID not in gym.registry:
        gym.register(KIN_ENV_ID, entry_point=KinematicTrackEnv, max_episode_steps=500)
    return KIN_ENV_ID
