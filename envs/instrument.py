"""A laser-tracker-like instrument: it samples the true tool point every ``measure_every`` control
steps, adds independent Gaussian noise of ``noise_mm`` per axis, loses a sample with probability
``dropout``, and delivers each one ``latency_steps`` control steps after it was taken. Turned off
(``enabled=False``) it models production running blind.

A measurement carries what an estimator needs to use it late: the encoder reading, the time and
the lab's columns (temperature, payload, dir1..dir6) *at the instant it was sampled*, as the
controller had them: the temperature sensor's reading and the declared payload.

The arm's temperature is read by a :class:`TemperatureSensor`: a first-order lag behind the
structure's temperature (``lag`` seconds, its time constant: a probe in the casting warms more
slowly than the links) plus independent Gaussian noise of ``noise`` kelvin per reading, one
reading per control step. At the start of an episode the arm has stood still, so the probe is
at the structure's temperature.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from arm.constraints import Interval, declare, problems, refuse
from arm.noise import NOISE_MM
from arm.so3 import rotation_matrix, rotation_vector
from envs.errors import InstrumentError

__all__ = [
    "InstrumentError",
    "LaserTracker",
    "Measurement",
    "TemperatureSensor",
    "TrackerConfig",
    "TrackerStation",
    "place_stations",
]


@dataclass(frozen=True)
class TrackerConfig:
    """Per-axis noise (mm, one standard deviation: :data:`arm.noise.NOISE_MM`; 0 draws none),
    the sampling period (control steps), the probability that a sample is lost, the delivery
    latency (control steps), on/off; each declared with its range (the env's options take
    them from here)."""

    noise_mm: float = declare(0.015, NOISE_MM, help="The simulated tracker's; 0 draws none.")
    measure_every: int = declare(5, Interval(int, 1, None, why="control steps"))
    dropout: float = declare(0.0, Interval(float, 0.0, 1.0, closed="left", why="a probability"))
    latency_steps: int = declare(0, Interval(int, 0, None, why="control steps"))
    enabled: bool = True

    def __post_init__(self) -> None:
        refuse(problems(self), InstrumentError)


@dataclass
class Measurement:
    """One delivered sample: the measured point (3,) m, the encoder reading (6,) rad, the time
    (s) and the columns (temperature, payload, dir1..dir6) at the instant it was sampled."""

    xyz: np.ndarray
    q: np.ndarray
    time: float
    step: int
    columns: dict[str, float] = field(default_factory=dict)


class LaserTracker:
    """See the module docstring. ``reset(rng)`` at each episode; ``sample(...)`` after every
    control step (it decides whether this step is sampled); ``deliver(step)`` returns the sample
    due at this step, if any."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config or TrackerConfig()
        self._sigma = self.config.noise_mm * 1e-3
        self._queue: deque[tuple[int, Measurement]] = deque()
        self._rng = np.random.default_rng(0)

    def reset(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._queue.clear()

    def due(self, step: int) -> bool:
        """Whether the tracker samples at control step ``step``."""
        c = self.config
        return c.enabled and step % c.measure_every == 0

    def sample(
        self,
        step: int,
        time: float,
        true_point: np.ndarray,
        q: np.ndarray,
        columns: dict[str, float],
    ) -> None:
        """Take a sample at ``step`` if one is due (noise and dropout drawn from the episode's
        generator)."""
        if not self.due(step):
            return
        noise = self._rng.normal(0.0, 1.0, 3)
        lost = self._rng.random() < self.config.dropout
        if lost:
            return
        m = Measurement(
            xyz=np.asarray(true_point, dtype=float) + self._sigma * noise,
            q=np.array(q, dtype=float),
            time=float(time),
            step=int(step),
            columns=dict(columns),
        )
        self._queue.append((step + self.config.latency_steps, m))

    @property
    def pending(self) -> bool:
        """Whether samples are waiting to be delivered."""
        return bool(self._queue)

    def deliver(self, step: int) -> Measurement | None:
        """The newest sample due by ``step`` (older ones due at the same time are superseded)."""
        out = None
        q = self._queue
        while q and q[0][0] <= step:
            out = q.popleft()[1]
        return out


class TemperatureSensor:
    """See the module docstring: ``reset(rng, temperature)`` at each episode (the probe settled at
    the structure's temperature), ``read(temperature, dt)`` once per control step with the
    structure's temperature now (degC): the probe follows it with time constant ``lag`` (s; 0: no
    lag) and each reading adds noise of standard deviation ``noise`` (K); a reading saturates at
    the ends of ``span`` (degC), the probe's range."""

    def __init__(
        self,
        noise: float = 0.1,
        lag: float = 3.0,
        span: tuple[float, float] = (-math.inf, math.inf),
    ) -> None:
        if not (np.isfinite(noise) and noise >= 0):
            raise InstrumentError(f"temperature_noise must be >= 0 K, got {noise}")
        if not (np.isfinite(lag) and lag >= 0):
            raise InstrumentError(f"temperature_lag must be >= 0 s, got {lag}")
        self.noise = float(noise)
        self.lag = float(lag)
        self.span = (float(span[0]), float(span[1]))  # the probe saturates at its ends
        self._probe = 20.0
        self._rng = np.random.default_rng(0)
        self.reading = 20.0

    def reset(self, rng: np.random.Generator, temperature: float) -> float:
        self._rng = rng
        self._probe = float(temperature)
        self.reading = self._saturate(self._probe + self.noise * float(rng.normal()))
        return self.reading

    def _saturate(self, value: float) -> float:
        return min(max(value, self.span[0]), self.span[1])

    def read(self, temperature: float, dt: float) -> float:
        # the exact step response of a first-order lag over dt, the input held over the step
        a = 1.0 if self.lag == 0 else 1.0 - math.exp(-dt / self.lag)
        self._probe += a * (float(temperature) - self._probe)
        self.reading = self._saturate(self._probe + self.noise * float(self._rng.normal()))
        return self.reading


@dataclass(frozen=True)
class TrackerStation:
    """Where a tracker stands for part of a campaign: its position (3,) and rotation (a rotation
    vector, 3) in the world frame. It measures in its own frame: ``x = R^T (p - c)``."""

    position: tuple[float, float, float]
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def R(self) -> np.ndarray:
        return rotation_matrix(np.asarray(self.rotation, dtype=float))

    def points(self, world: np.ndarray) -> np.ndarray:
        """World points (N, 3) in the station's frame."""
        return (np.asarray(world, dtype=float) - np.asarray(self.position)) @ self.R

    def rotations(self, world: np.ndarray) -> np.ndarray:
        """World rotations (N, 3, 3) (world <- frame) seen from the station (station <- frame)."""
        return np.einsum("ji,njk->nik", self.R, np.asarray(world, dtype=float))

    def distance(self, world: np.ndarray) -> np.ndarray:
        """Distance (N,) of world points from the tracker, m."""
        return np.linalg.norm(np.asarray(world, dtype=float) - np.asarray(self.position), axis=1)


def place_stations(
    n: int,
    rng: np.random.Generator,
    distance: tuple[float, float] = (2.0, 6.0),
    height: tuple[float, float] = (0.0, 1.2),
) -> list[TrackerStation]:
    """``n`` tracker stations around an arm at the world origin: spread in azimuth (a random turn
    of evenly spaced directions, each jittered), ``distance`` m from the base's axis, ``height`` m
    above the floor, each turned about the vertical by a random angle and levelled to within
    a few mrad (a tracker stands on a tripod). The station's frame is arbitrary: the lab
    registers each station's base."""
    if int(n) != n or n < 1:
        raise InstrumentError(f"stations must be a positive integer, got {n}")
    start = rng.uniform(0.0, 2.0 * math.pi)
    out = []
    for k in range(int(n)):
        azimuth = start + 2.0 * math.pi * k / n + rng.uniform(-0.3, 0.3)
        r = rng.uniform(*distance)
        z = rng.uniform(*height)
        tilt = rng.normal(0.0, 3e-3, 2)
        yaw = rng.uniform(-math.pi, math.pi)
        rot = rotation_matrix(np.array([tilt[0], tilt[1], 0.0])) @ rotation_matrix(
            np.array([0.0, 0.0, yaw])
        )
        rx, ry, rz = (float(v) for v in rotation_vector(rot))
        out.append(TrackerStation((r * math.cos(azimuth), r * math.sin(azimuth), z), (rx, ry, rz)))
    return out
