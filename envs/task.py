"""The task contract between the environment and its controllers, free of MuJoCo.

    task = env.unwrapped.task                 # TaskInfo: what any controller may know
    o = Observation.parse(task, obs)          # the flat observation by name
    seen = controller_info(info)              # the part of a step's info a controller may use
    truth = env.unwrapped.truth               # satisfies Truth: for oracles and evaluation only

:class:`TaskInfo` describes the *nominal* arm, the timing, the servo limits, the instruments'
settings and the observation layout; it does not name the scenario (which hidden effects the arm
has is for the controller to find out). :data:`CONTROLLER_INFO_KEYS` are the keys of a step's
``info`` a real controller has: the tracker's measurement, the reference, the time, the divergence
flag; everything else in ``info`` (the true tool point and error, the reward's parts, the plant's
exact temperature and payload) is for evaluation, and :func:`agents.runner.run_episode` hands
controllers only :func:`controller_info` of it. :class:`Truth` is what an oracle controller may
read of the plant's hidden arm; the env's :class:`envs.scenarios.EpisodeTruth` satisfies it.
Importing this module loads neither the plant nor MuJoCo, so a controller can be written and
tested against the contract alone.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from arm.description import RobotDescription
from arm.errormodel import ErrorModel
from envs.errors import ObservationError

__all__ = ["CONTROLLER_INFO_KEYS", "Observation", "TaskInfo", "Truth", "controller_info"]

#: The keys of a step's ``info`` that a real controller has: the tracker's measurement (the point,
#: the encoder reading, the time it was sampled and the columns as the sensors gave them then:
#: the temperature sensor's reading, the declared payload, the directions of motion), the
#: reference now, the time and whether the simulation diverged.
CONTROLLER_INFO_KEYS = frozenset(
    {
        "measurement",
        "measurement_q",
        "measurement_time",
        "measurement_valid",
        "measurement_columns",
        "reference",
        "time",
        "diverged",
    }
)


def controller_info(info: Mapping[str, Any]) -> dict[str, Any]:
    """The part of a step's ``info`` a controller may use (:data:`CONTROLLER_INFO_KEYS`)."""
    return {k: v for k, v in info.items() if k in CONTROLLER_INFO_KEYS}


@dataclass(frozen=True, eq=False)
class TaskInfo:
    """What a controller may know: the *nominal* arm, the timing, the servo limits and the
    instrument's settings, and where each part of the observation sits.

    ``robot`` nominal description; ``dt`` control period (s); ``v_max``/``a_max`` (6,) the servo's
    velocity and acceleration limits (a command is ``action * v_max``, rate-limited to
    ``a_max * dt`` per step); ``q_lower``/``q_upper`` (6,) joint limits; ``preview_steps``;
    ``obs_slices`` {name: slice} into the observation; ``noise_mm`` per-axis tracker noise;
    ``measure_every`` (steps), ``latency_steps``, ``dropout``, ``measurements`` (False: blind);
    ``temperature_noise`` (K, one standard deviation) and ``temperature_lag`` (s, the time
    constant of its first-order lag) of the temperature sensor; ``physics_dt`` and ``substeps``;
    ``torque_max`` (6,); ``jerk_weight``. Not the scenario: that is hidden.
    """

    robot: RobotDescription
    dt: float
    v_max: np.ndarray
    a_max: np.ndarray
    q_lower: np.ndarray
    q_upper: np.ndarray
    preview_steps: int
    obs_slices: dict[str, slice]
    noise_mm: float
    measure_every: int
    latency_steps: int
    dropout: float
    measurements: bool
    temperature_noise: float
    temperature_lag: float
    physics_dt: float
    substeps: int
    torque_max: np.ndarray
    jerk_weight: float

    @property
    def obs_size(self) -> int:
        return max(s.stop for s in self.obs_slices.values())


class Truth(Protocol):
    """What an oracle controller may read of the plant's hidden arm.

    ``true_robot``: the description with the true geometric errors folded in; ``model`` and
    ``params``: an error model on the *nominal* arm and its true parameter vector (laid out by
    ``model.layout``), whose tool point is the plant's (exactly for a settled arm where the
    scenario's physics is the lab's formulas); ``scenario``: its name; :meth:`conditions`: the
    plant's exact temperature (degC) and payload (kg) now, which an oracle takes from here rather
    than from the observation's sensor reading and declared payload.
    """

    @property
    def scenario(self) -> str: ...

    def conditions(self) -> Mapping[str, float]: ...

    @property
    def true_robot(self) -> RobotDescription: ...

    @property
    def model(self) -> ErrorModel: ...

    @property
    def params(self) -> np.ndarray: ...


@dataclass(frozen=True)
class Observation:
    """The named parts of a flat observation vector (views, SI units)."""

    q: np.ndarray  # encoder angles (6,), rad
    qd: np.ndarray  # joint velocities (6,), rad/s
    ref: np.ndarray  # the reference tool point now (3,), m
    preview: np.ndarray  # the next references (preview_steps, 3), m
    meas: np.ndarray  # the last tracker measurement (3,), m
    meas_age: float  # its age, s
    meas_valid: bool
    temperature: float  # degC, as the arm's temperature sensor reads it (noisy, lagging)
    payload: float | None = None  # kg, as the operator declared it (None: not observed)

    @classmethod
    def parse(cls, task: TaskInfo, obs: np.ndarray) -> Observation:
        sl = task.obs_slices
        obs = np.asarray(obs, dtype=float)

        def part(name: str, default: np.ndarray | None = None) -> np.ndarray:
            if name not in sl:
                if default is None:
                    raise ObservationError(
                        f"the observation has no {name!r} (slices: {sorted(sl)})"
                    )
                return default
            return obs[sl[name]]

        return cls(
            q=part("q"),
            qd=part("qd", np.zeros(6)),
            ref=part("ref"),
            preview=part("preview").reshape(-1, 3),
            meas=part("meas", np.full(3, np.nan)),
            meas_age=float(part("meas_age", np.array([np.inf]))[0]),
            meas_valid=bool(part("meas_valid", np.zeros(1))[0] > 0.5),
            temperature=float(part("temperature", np.array([20.0]))[0]),
            payload=float(obs[sl["payload"]][0]) if "payload" in sl else None,
        )

    def shifted(self, delta: np.ndarray) -> Observation:
        """The same observation with the reference and its preview moved by ``delta`` (3,) m."""
        d = np.asarray(delta, dtype=float).reshape(3)
        return replace(self, ref=self.ref + d, preview=self.preview + d)

    def references(self, n: int) -> np.ndarray:
        """The next ``n`` reference points (n, 3), the last preview point repeated if short."""
        pv = self.preview
        if len(pv) == 0:
            return np.repeat(self.ref[None, :], n, axis=0)
        if len(pv) >= n:
            return pv[:n]
        return np.vstack([pv, np.repeat(pv[-1:], n - len(pv), axis=0)])
