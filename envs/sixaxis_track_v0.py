"""``SixAxisTrack-v0``: track a reference path with the tool point of a six-axis arm whose true
geometry and physics differ from its description, seen through encoders and a laser tracker.

It is one module, longer than most, because the environment's docstring is its reference (spaces,
reward, termination, info) and stays beside the code that makes them.
"""

from __future__ import annotations

import inspect
import itertools
import math
import os
import warnings
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit

from arm.constraints import Constraint, Interval, OneOf, TypeOf, constraints_of, description
from arm.description import RobotDescription, load_robot
from arm.errors import SixAxisError
from envs.errors import ActionError, EnvOptionError, EnvStateError
from envs.instrument import InstrumentError, LaserTracker, TemperatureSensor, TrackerConfig
from envs.plant import MAX_SPEED, PHYSICS_DT, SUBSTEPS, Plant
from envs.scenarios import SCENARIOS, EpisodeTruth, Scenario, draw_truth, get_scenario
from envs.simulator import SimulatorError, mujoco
from envs.task import TaskInfo
from envs.trajectories import KINDS, Trajectory, check_posture, sample_trajectory

__all__ = ["EnvOptionError", "EnvStateError", "SixAxisTrackEnv", "make_env"]

MAX_MEASUREMENT_AGE = 10.0  # s, the age reported before the first measurement

WORKSPACE = 5.0  # m, bound of every observed point
DIVERGENCE_REWARD = -1000.0


#: What the observation's sensors read (its ``observation_space``): the arm's temperature probe
#: (degC, saturating at its ends, as a real probe does) and the declared payload (kg).
TEMPERATURE_RANGE = (-50.0, 200.0)
PAYLOAD_RANGE = (0.0, 100.0)


def _outside_observation(overrides: Any) -> str | None:
    """Why ``overrides`` would put the observation outside ``observation_space`` (a start
    temperature the probe cannot read, a payload beyond its range), or None."""
    if not isinstance(overrides, dict):
        return None
    for effect, key, (lo, hi), unit, hint in (
        ("thermal", "temperature0", TEMPERATURE_RANGE, "degC", " (kelvin given as degC?)"),
        ("payload", "payload0", PAYLOAD_RANGE, "kg", ""),
        ("payload", "payload1", PAYLOAD_RANGE, "kg", ""),
    ):
        table = overrides.get(effect)
        value = table.get(key) if isinstance(table, dict) else None
        if value is None:
            continue
        try:
            v = np.atleast_1d(np.asarray(value, dtype=float))
        except (TypeError, ValueError):
            continue  # draw_truth names it
        if not np.all((v >= lo) & (v <= hi)):
            return (
                f"{effect}.{key} = {value!r} lies outside what the observation reports "
                f"({lo:g} to {hi:g} {unit}){hint}"
            )
    return None


def make_env(
    interface: str = "joint",
    tool_step_mm: float = 5.0,
    observe: Sequence[str] = (),
    **kwargs: Any,
) -> gym.Env:
    """``SixAxisTrack-v0`` as ``gym.make`` builds it: the env in a ``TimeLimit`` of its own
    ``episode_seconds`` (500 steps by default), so that the episode and the limit agree.
    ``interface="tool"`` puts the operational-space interface around it
    (:class:`envs.wrappers.ToolDisplacementAction`: a tool displacement of up to ``tool_step_mm``
    mm per step and axis, relative observations in mm, followed by the env's own readings that
    ``observe`` names: ``"joints"``, ``"payload"``, ``"temperature"``); ``"joint"`` (the default)
    is the env's own, normalised joint velocities. ``make_env.env_class`` is the env's class (its
    options, ``check_options``)."""
    from envs.wrappers import INTERFACES, OBSERVABLE, ToolDisplacementAction

    problems = {}
    for key, value, constraint in (
        ("interface", interface, OneOf(tuple(INTERFACES))),
        ("tool_step_mm", tool_step_mm, Interval(float, 0.0, None, closed="neither", why="mm")),
    ):
        if not constraint.holds(value):
            problems[key] = f"expected {description(constraint)}, got {value!r}"
    names = list(observe) if isinstance(observe, list | tuple) else None
    if names is None or any(n not in OBSERVABLE for n in names) or len(set(names)) < len(names):
        problems["observe"] = f"expected distinct names of {', '.join(OBSERVABLE)}, got {observe!r}"
    elif names and interface != "tool":
        problems["observe"] = "is an option of the tool interface (interface='tool')"
    if problems:
        raise EnvOptionError(
            "SixAxisTrack-v0: " + "; ".join(f"{k}: {m}" for k, m in problems.items())
        )
    env = SixAxisTrackEnv(**kwargs)
    limited = TimeLimit(env, env.episode_steps)
    if interface == "tool":
        return ToolDisplacementAction(limited, float(tool_step_mm), observe=tuple(observe))
    return limited


def _option_names(cls: type) -> frozenset[str]:
    """The keyword arguments of an env class's constructor."""
    return frozenset(inspect.signature(cls.__init__).parameters) - {"self"}  # type: ignore[misc]


def _check_instrument(o: dict[str, Any], problems: dict[str, str]) -> None:
    """The laser tracker's own rules on its options, by the key its message starts with."""
    if "noise_mm" in problems or "measure_every" in problems:
        return
    try:
        TrackerConfig(
            noise_mm=o["noise_mm"],
            measure_every=o["measure_every"],
            dropout=o["dropout"],
            latency_steps=o["latency_steps"],
        )
    except InstrumentError as exc:
        key = str(exc).split(" ", 1)[0]
        problems.setdefault(key if key in o else "noise_mm", str(exc))


def _check_world(o: dict[str, Any], problems: dict[str, str]) -> None:
    """The robot, the posture on it and the scenario's overrides, drawn once as a reset would."""
    robot = o["robot"]
    nominal = None
    if isinstance(robot, RobotDescription):
        nominal = robot.to_modified()
    elif not isinstance(robot, str):
        problems.setdefault(
            "robot", f"expected a robot name, a TOML file or a RobotDescription, got {robot!r}"
        )
    else:
        try:
            nominal = load_robot(robot).to_modified()
        except (SixAxisError, OSError) as exc:
            problems["robot"] = str(exc)
    if nominal is not None and o["posture"] is not None:
        try:
            check_posture(nominal, o["posture"])
        except (SixAxisError, ValueError) as exc:
            problems["posture"] = str(exc)
    if nominal is not None and "scenario" not in problems:
        try:
            draw_truth(o["scenario"], nominal, np.random.default_rng(0), o["overrides"])
        except (SixAxisError, ValueError) as exc:
            problems["overrides"] = str(exc)
        else:
            why = _outside_observation(o["overrides"])
            if why:
                problems["overrides"] = why


def _observation_space(nominal: RobotDescription, slices: dict[str, slice], n: int) -> spaces.Box:
    """The observation's bounds, entry by entry (:func:`_layout`)."""
    low = np.empty(n, dtype=np.float32)
    high = np.empty(n, dtype=np.float32)
    low[slices["q"]] = nominal.lower - math.pi  # hard stops sit at the limits
    high[slices["q"]] = nominal.upper + math.pi
    for name, lo, hi in (
        ("qd", -MAX_SPEED, MAX_SPEED),
        ("ref", -WORKSPACE, WORKSPACE),
        ("preview", -WORKSPACE, WORKSPACE),
        ("meas", -WORKSPACE, WORKSPACE),
        ("meas_age", 0.0, MAX_MEASUREMENT_AGE),
        ("meas_valid", 0.0, 1.0),
        ("temperature", *TEMPERATURE_RANGE),
        ("payload", *PAYLOAD_RANGE),
    ):
        low[slices[name]], high[slices[name]] = lo, hi
    return spaces.Box(low, high, (n,), np.float32)


#: the largest rendered frame, pixels per side (4K video is 3840 x 2160; MuJoCo's offscreen buffer
#: and the H.264 encoder refuse frames far beyond)
MAX_FRAME = 4096
#: the modes ``render`` draws
RENDER_MODES = ("rgb_array",)
_CONTROL_DT = PHYSICS_DT * SUBSTEPS

#: the tracker's options, as the instrument declares them (:class:`envs.instrument.TrackerConfig`)
_TRACKER = constraints_of(TrackerConfig)
_TRACKER_OPTIONS = ("noise_mm", "measure_every", "dropout", "latency_steps")

#: what each plain option may be (:mod:`arm.constraints`; ``True``: None too), in the constructor's
#: order; the scenario, the robot, the posture and the overrides are judged by the libraries that
#: read them (:func:`envs.scenarios.draw_truth`, :func:`arm.description.load_robot`,
#: :func:`envs.trajectories.check_posture`) and the instrument's options by its own rules too
OPTION_CONSTRAINTS: dict[str, tuple[Constraint, bool]] = {
    "trajectory": (OneOf(KINDS), True),
    **{k: (_TRACKER[k][0][0], False) for k in _TRACKER_OPTIONS},
    "measurements": (TypeOf(bool), False),
    "temperature_noise": (Interval(float, 0.0, None, why="K"), False),
    "temperature_lag": (Interval(float, 0.0, None, why="s"), False),
    "preview_steps": (Interval(int, 0, None), False),
    "jerk_weight": (Interval(float, 0.0, None), False),
    "episode_seconds": (Interval(float, _CONTROL_DT, None, why="one control step"), False),
    "render_mode": (OneOf(RENDER_MODES), True),
    "width": (Interval(int, 1, MAX_FRAME, why="pixels"), False),
    "height": (Interval(int, 1, MAX_FRAME, why="pixels"), False),
}


def _layout(preview: int) -> dict[str, slice]:
    sizes = (
        ("q", 6),
        ("qd", 6),
        ("ref", 3),
        ("preview", 3 * preview),
        ("meas", 3),
        ("meas_age", 1),
        ("meas_valid", 1),
        ("temperature", 1),
        ("payload", 1),
    )
    out, k = {}, 0
    for name, n in sizes:
        out[name] = slice(k, k + n)
        k += n
    return out


class SixAxisTrackEnv(gym.Env):
    """
    ## Description
    A six-axis industrial arm (the seed arm of docs/format.md unless another description is
    given) simulated in MuJoCo must move its tool point along a reference path. The arm the agent
    is told about (``task.robot``) is the *nominal* one; the simulated arm carries randomised DH,
    base and tool errors and, per scenario, hidden physical effects (elastic joints, gear
    transmission error, backlash, thermal growth, payload changes) made by the physics of the
    plant (``envs/plant.py``). The agent sees the motor-side encoders and, every few steps, a
    noisy laser-tracker measurement of the true tool point. Control at 50 Hz (``dt = 0.02 s``)
    over 1 kHz physics (20 substeps).

    ## Action Space
    ``Box(-1, 1, (6,), float32)``: normalised joint-velocity commands. The servo of axis i is
    commanded ``action[i] * v_max[i]`` rad/s (``task.v_max``), rate-limited to ``a_max[i] * dt``
    per step (``task.a_max``); its position loop integrates the command within the joint limits
    and its torque is limited to ``task.torque_max``. Values outside [-1, 1] are clipped; NaN, inf
    or a wrong shape raise :class:`~envs.errors.ActionError` (a ``ValueError``).

    | Num | Action                         | Min | Max | Joint  | Unit               |
    |-----|--------------------------------|-----|-----|--------|--------------------|
    | 0   | velocity command of axis 1     | -1  | 1   | motor1 | fraction of v_max  |
    | 1   | velocity command of axis 2     | -1  | 1   | motor2 | fraction of v_max  |
    | 2   | velocity command of axis 3     | -1  | 1   | motor3 | fraction of v_max  |
    | 3   | velocity command of axis 4     | -1  | 1   | motor4 | fraction of v_max  |
    | 4   | velocity command of axis 5     | -1  | 1   | motor5 | fraction of v_max  |
    | 5   | velocity command of axis 6     | -1  | 1   | motor6 | fraction of v_max  |

    Seed arm: ``v_max = (1.2, 1.2, 1.5, 2.5, 2.5, 3.0)`` rad/s, ``a_max = (6, 6, 8, 12, 12, 15)``
    rad/s^2.

    ## Observation Space
    ``Box(low, high, (22 + 3 * preview_steps,), float32)`` (52 with the default preview of 10),
    with the finite bounds below; ``task.obs_slices`` names each part. All points are in the
    measurement frame (the nominal robot base frame, z up), in metres.

    | Num        | Observation                                         | Min           | Max           | Name (obs_slices) | Unit    |
    |------------|-----------------------------------------------------|---------------|---------------|-------------------|---------|
    | 0-5        | encoder angles of axes 1-6 (motor side)             | lower - pi    | upper + pi    | q                 | rad     |
    | 6-11       | encoder velocities of axes 1-6                      | -100          | 100           | qd                | rad/s   |
    | 12-14      | reference tool point now (x, y, z)                  | -5            | 5             | ref               | m       |
    | 15-44      | the next ``preview_steps`` reference points         | -5            | 5             | preview           | m       |
    | 45-47      | last laser-tracker measurement (zeros before one)   | -5            | 5             | meas              | m       |
    | 48         | age of that measurement (10 before the first)       | 0             | 10            | meas_age          | s       |
    | 49         | 1 if a new measurement arrived this step, else 0    | 0             | 1             | meas_valid        | 0/1     |
    | 50         | arm temperature, as its sensor reads it (see below) | -50           | 200           | temperature       | degC    |
    | 51         | payload mass, as the operator declared it           | 0             | 100           | payload           | kg      |

    ``lower``/``upper`` are the description's joint limits (the bounds leave a half-turn either
    way for the hard stops); 100 rad/s is the plant's ``MAX_SPEED``, 5 m the env's ``WORKSPACE``.

    (indices for ``preview_steps=10``; with P preview steps the preview spans 15..15+3P-1 and the
    rest shifts.)

    The two conditions are sensors, not the plant's state. ``temperature`` is a probe on the arm:
    a first-order lag of ``temperature_lag`` (3 s) behind the structure's temperature, plus
    Gaussian noise of ``temperature_noise`` (0.1 K, one standard deviation) on every reading
    (``task.temperature_noise``/``task.temperature_lag``). ``payload`` is what the operator
    declared: right at the start; in the ``payload`` scenario the change is declared 0.5-3 s late
    and 0-0.5 kg off (drawn per episode; ``overrides={"payload": {"declare_delay": 0,
    "declare_error": 0}}`` declares it at once and right), so a controller must notice the change
    in its measurements.

    ## The tool interface
    ``gym.make("SixAxisTrack-v0", interface="tool", tool_step_mm=5.0, observe=[...])``
    (:class:`envs.wrappers.ToolDisplacementAction`): the action ``Box(-1, 1, (3,))`` is a tool
    displacement of up to ``tool_step_mm`` mm per step and axis; the observation is relative and
    not normalised. Each index has a declared fixed scale (the wrapper's ``feature_offset`` and
    ``feature_scale``): ``(obs - offset) / scale`` is of order 1, and is what the trainer feeds
    its networks (``obs_normalization = "fixed"``) and saves with the policy.

    | Num   | Observation                                            | Min        | Max        | Name (obs_slices) | Unit  | Offset | Scale   |
    |-------|--------------------------------------------------------|------------|------------|-------------------|-------|--------|---------|
    | 0-2   | reference minus the tool point as the nominal model,   | -1e4       | 1e4        | tracking_error    | mm    | 0      | 1       |
    |       | corrected by the last measured model error, places it |            |            |                   |       |        |         |
    | 3-32  | the next 10 references minus the reference now         | -1e4       | 1e4        | preview           | mm    | 0      | step_mm |
    | 33-35 | model error at the last measurement (0 before one)     | -1e4       | 1e4        | model_error       | mm    | 0      | 1       |
    | 36    | its age, capped at 1 (1 before the first)              | 0          | 1          | model_error_age   | s     | 0      | 0.1     |
    | 37-39 | the last action                                        | -1         | 1          | previous_action   | 1     | 0      | 1       |
    | 40-45 | ``"joints"``: encoder angles of axes 1-6               | lower - pi | upper + pi | q                 | rad   | 0      | 1       |
    | 46-51 | ``"joints"``: encoder velocities of axes 1-6           | -100       | 100        | qd                | rad/s | 0      | 1       |
    | 52    | ``"payload"``: payload, as the operator declared it    | 0          | 100        | payload           | kg    | 0      | 1       |
    | 53    | ``"temperature"``: arm temperature, as its sensor reads | -50       | 200        | temperature       | degC  | 20     | 5       |

    (indices for ``preview_steps=10`` and ``observe=["joints", "payload", "temperature"]``; the
    parts of ``observe`` come in this order, whatever the order given, and one left out shifts
    those after it.)

    ## Rewards
    ``reward = reward_tracking + reward_jerk`` with ``reward_tracking = -|p_true - p_ref|`` in mm
    (the plant's true tool point, not the measured one) and ``reward_jerk = -jerk_weight *
    |a_t - 2 a_{t-1} + a_{t-2}|^2`` (the command's second difference; ``jerk_weight`` 0.01).
    ``_get_rew()`` returns ``(reward, reward_info)``; both parts are in ``info``. A diverged
    simulation scores ``-1000`` once and ends the episode.

    ## Info
    Every step (and reset) gives: ``true_error_mm`` (float), ``true_tool`` (3,), ``reference``
    (3,), ``measurement_valid`` (bool: a new measurement arrived this step), ``reward_tracking``,
    ``reward_jerk``, ``diverged``, ``time`` (s), ``temperature`` (degC) and ``payload`` (kg) (the
    plant's exact values), ``trajectory`` (kind). When ``measurement_valid`` is True it also
    gives ``measurement`` (3,) the measured point, ``measurement_q`` (6,) the encoder reading at
    the instant that point was sampled (it differs from the current one with latency),
    ``measurement_time`` (s, when sampled) and ``measurement_columns`` {t, temperature, payload,
    dir1..dir6} at that instant as the controller had them (the sensor's temperature, the
    declared payload, the commanded directions); without a new measurement these keys are absent
    (use ``info.get``; Gymnasium's vector envs mask them), never NaN, so that equal seeds give
    equal infos.

    | info key                                   | who gets it                                    |
    |--------------------------------------------|------------------------------------------------|
    | `measurement`, `measurement_q`, `measurement_time`, `measurement_valid`, `measurement_columns` | controllers |
    | `reference`, `time`, `diverged`            | controllers                                    |
    | `true_error_mm`, `true_tool`, `reward_tracking`, `reward_jerk`, `temperature`, `payload`, `trajectory` | evaluation only |

    The benchmark's runner (``agents.runner.run_episode``) hands a controller's ``act`` only the
    controllers' keys (``envs.task.controller_info``); an RL policy learns from the reward, which
    is the true error, like any Gymnasium env's.

    ## Scenarios
    Magnitudes are drawn per episode from the seed (docs/format.md; ``envs.scenarios.RANGES``)
    and every one can be overridden (``overrides={"compliance": {"c2": 8e-6}}``).

    | scenario       | hidden effects (made by the plant's physics)                                  |
    |----------------|-------------------------------------------------------------------------------|
    | `nominal`      | none: the arm is its description                                              |
    | `geometric`    | DH errors (lengths 0.1-0.3 mm, angles 0.6-1.5 mrad), Hayati beta, base, tool   |
    | `compliance`   | + elastic joints, c = 1/k of 3e-6..1e-5 rad/(N m): gravity sag, vibration      |
    | `transmission` | + gear eccentricity ts, tc and gear-ratio error g, 1e-4..5e-4 (stiff mesh)     |
    | `backlash`     | + gaps of 3e-4..6e-4 rad: loaded side under gravity, lagging under friction    |
    | `thermal`      | + link growth, kappa 1.2e-5..2.3e-5 /K, start 20-35 degC, heating with motion  |
    | `payload`      | + elastic joints and a payload of 0-2 kg that changes to 0-3 kg at 3-7 s       |
    | `all`          | everything at once (but the cyclic errors)                                    |
    | `cyclic`       | + cyclic joint errors, 2 orders of 2-40 per turn on 3 joints, 0.05-0.3 mrad    |

    ## Hidden truth
    ``env.unwrapped.task`` (:class:`~envs.task.TaskInfo`) is what an agent may use; it does not
    name the scenario. ``env.unwrapped.truth`` (:class:`~envs.scenarios.EpisodeTruth`) is for
    evaluation and oracle controllers only: the scenario, the true description, an
    ``ErrorModel`` approximating the plant with its true ``params``, the raw magnitudes, and
    ``truth.conditions()``, the plant's exact temperature and payload now.

    ## Starting State
    ``reset(seed=...)`` draws the truth (scenario magnitudes), the trajectory and the instrument
    noise from the seed: the same seed gives the same episode bit for bit. The arm starts at rest
    with its encoders at the nominal inverse kinematics of the path's start (so the true tool is
    off by the arm's errors), links at their static deflection, backlash against the loaded side
    or lagging a random last direction. ``options={"trajectory": "circle"}`` picks the path kind
    for one episode, ``options={"posture": [None, -1.6, 0.6, None, None, None]}`` its region (see
    the ``posture`` argument).

    ## Episode End
    Terminates only if the simulation diverges (``info["diverged"]``). Truncated after
    ``episode_seconds`` (500 steps, 10 s, by default) by the ``TimeLimit`` that ``gym.make``
    puts around it (:func:`make_env`); a ``max_episode_steps`` given to ``gym.make`` can only
    shorten the episode. ``step`` and ``render`` after ``close`` are refused (``EnvStateError``)
    until the next ``reset``.

    ## Arguments
    | Parameter       | Type        | Default       | Description                                                  |
    |-----------------|-------------|---------------|--------------------------------------------------------------|
    | `scenario`      | str         | `"geometric"` | nominal, geometric, compliance, transmission, backlash, thermal, payload, all, cyclic |
    | `overrides`     | dict        | `None`        | `{effect: {param: value or (lo, hi)}}`, see `envs.scenarios`  |
    | `trajectory`    | str or None | `None`        | circle, lemniscate, lines, spline; None draws one per reset  |
    | `posture`       | 6 floats/None or None | `None` | joint angles (rad; None: drawn) around which the path is drawn: its region of the workspace |
    | `noise_mm`      | float       | `0.015`       | tracker noise per axis (1 sigma), mm                         |
    | `measure_every` | int         | `5`           | tracker sampling period, control steps                       |
    | `dropout`       | float       | `0.0`         | probability that a sample is lost                            |
    | `latency_steps` | int         | `0`           | delivery delay of a sample, control steps                    |
    | `measurements`  | bool        | `True`        | False: no tracker (production running blind)                 |
    | `temperature_noise` | float   | `0.1`         | temperature sensor noise per reading (1 sigma), K            |
    | `temperature_lag` | float     | `3.0`         | time constant of the temperature sensor's first-order lag, s |
    | `preview_steps` | int         | `10`          | reference points ahead in the observation                    |
    | `jerk_weight`   | float       | `0.01`        | weight of the command-jerk penalty                           |
    | `robot`         | str or RobotDescription | `"seed"` | the nominal arm (needs a mass model)                  |
    | `episode_seconds` | float     | `10.0`        | the episode's length (its TimeLimit) and the reference computed per reset |
    | `render_mode`   | str or None | `None`        | `"rgb_array"`: the arm, the reference path (green), the true tool path (blue), the measured points (red) |
    | `width`, `height` | int       | `640`, `480`  | rendered frame size, at most 4096 pixels a side              |

    An option out of range or of the wrong type is an ``EnvOptionError`` (a ``ValueError``) naming
    every key at fault; ``SixAxisTrackEnv.check_options(**kwargs)`` returns the same problems
    without building the simulation. ``step`` or ``render`` before ``reset`` is an
    ``EnvStateError`` (Gymnasium's ``ResetNeeded``).

    ## Version History
    * v0: initial version (not released; changed in place). The observation's temperature is a
      sensor (noise and lag) and its payload the operator's declaration (late and wrong in the
      ``payload`` scenario), no longer the plant's exact values; ``TaskInfo`` no longer names the
      scenario; controllers get only the controllers' info keys from the runner.
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 50}

    def __init__(
        self,
        scenario: str | Scenario = "geometric",
        overrides: dict[str, dict[str, Any]] | None = None,
        trajectory: str | None = None,
        posture: Sequence[float | None] | None = None,
        noise_mm: float = 0.015,
        measure_every: int = 5,
        dropout: float = 0.0,
        latency_steps: int = 0,
        measurements: bool = True,
        temperature_noise: float = 0.1,
        temperature_lag: float = 3.0,
        preview_steps: int = 10,
        jerk_weight: float = 0.01,
        robot: str | RobotDescription = "seed",
        episode_seconds: float = 10.0,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
    ) -> None:
        # the arguments as given (the first statement: locals() holds nothing else yet)
        given = {k: v for k, v in locals().items() if k in _option_names(type(self))}
        problems = self.check_options(**given)
        if problems:
            raise EnvOptionError(
                "SixAxisTrack-v0: " + "; ".join(f"{k}: {m}" for k, m in problems.items())
            )
        self.scenario = get_scenario(scenario)
        self.overrides = overrides
        self.trajectory_kind = trajectory
        self.render_mode = render_mode
        self.width, self.height = int(width), int(height)
        self.jerk_weight = float(jerk_weight)
        nominal = robot if isinstance(robot, RobotDescription) else load_robot(robot)
        self.nominal = nominal.to_modified()
        # a region of the workspace for the path (checked now, not at the first reset)
        self.posture = (
            None
            if posture is None
            else tuple(
                None if math.isnan(v) else float(v) for v in check_posture(self.nominal, posture)
            )
        )
        self.plant = Plant(self.nominal, elastic=self.scenario.elastic)
        self.tracker = LaserTracker(
            TrackerConfig(
                noise_mm=float(noise_mm),
                measure_every=int(measure_every),
                dropout=float(dropout),
                latency_steps=int(latency_steps),
                enabled=bool(measurements),
            )
        )
        self.thermometer = TemperatureSensor(
            float(temperature_noise), float(temperature_lag), TEMPERATURE_RANGE
        )
        drive = self.plant.drive
        P = int(preview_steps)
        slices = _layout(P)
        self.task = TaskInfo(
            robot=self.nominal,
            dt=self.plant.dt,
            v_max=drive.v_max.copy(),
            a_max=drive.a_max.copy(),
            q_lower=self.nominal.lower,
            q_upper=self.nominal.upper,
            preview_steps=P,
            obs_slices=slices,
            noise_mm=float(noise_mm),
            measure_every=int(measure_every),
            latency_steps=int(latency_steps),
            dropout=float(dropout),
            measurements=bool(measurements),
            temperature_noise=self.thermometer.noise,
            temperature_lag=self.thermometer.lag,
            physics_dt=self.plant.physics_dt,
            substeps=self.plant.substeps,
            torque_max=drive.torque_max.copy(),
            jerk_weight=self.jerk_weight,
        )
        self.dt = self.plant.dt
        self.episode_steps = round(float(episode_seconds) / self.dt)
        self.action_space = spaces.Box(-1.0, 1.0, (6,), np.float32)
        self.observation_space = _observation_space(self.nominal, slices, self.task.obs_size)
        self._init_episode_state(slices, drive.v_max, P)

    def _init_episode_state(self, slices: dict[str, slice], v_max: np.ndarray, P: int) -> None:
        """The per-episode state, before the first reset."""
        n = self.task.obs_size
        self.truth: EpisodeTruth | None = None
        self.trajectory: Trajectory | None = None
        self.references = np.zeros((1, 3))
        self._obs = np.zeros(n)
        self._sl = slices
        self._v_max = v_max.astype(float)
        self._a = np.zeros(6)
        self._a1 = np.zeros(6)
        self._a2 = np.zeros(6)
        self._k = 0
        self._temperature = 20.0  # the sensor's reading and the declared payload of this step
        self._payload = 0.0
        self._diverged = False
        self._meas_time = math.nan
        self._meas_points: list[np.ndarray] = []
        self._tool_trail: list[np.ndarray] = []  # the true tool points, kept when rendering
        self._renderer: mujoco.Renderer | None = None
        self._camera: mujoco.MjvCamera | None = None  # free camera; adjust it at will
        self._camera_target: Trajectory | None = None
        self._ref_sl = slices["ref"]
        self._prev_sl = slices["preview"]
        self._q_sl, self._qd_sl = slices["q"], slices["qd"]
        self._valid_i = slices["meas_valid"].start
        self._age_i = slices["meas_age"].start
        self._temp_i = slices["temperature"].start
        self._payload_i = slices["payload"].start
        self._P = P
        self._j = np.zeros(6)
        self._closed = False

    @classmethod
    def check_options(cls, **options: Any) -> dict[str, str]:
        """What is wrong with these keyword arguments, ``{key: problem}`` (empty: the env takes
        them), without building the simulation. The constructor refuses the same, and a sweep's
        config checks every run's options with it before any run starts. The plain options are
        judged by their declarations (:data:`OPTION_CONSTRAINTS`), the others by the libraries
        that read them."""
        params = inspect.signature(cls.__init__).parameters
        defaults = {k: p.default for k, p in params.items() if k != "self"}
        problems: dict[str, str] = {}
        for k in options:
            if k not in defaults:
                problems[k] = f"unknown option; the env takes {', '.join(defaults)}"
        o = defaults | {k: v for k, v in options.items() if k in defaults}
        sc = o["scenario"]
        if not isinstance(sc, (Scenario, str)):
            problems["scenario"] = f"expected a scenario name, got {sc!r}"
        elif isinstance(sc, str) and sc not in SCENARIOS:
            problems["scenario"] = f"unknown scenario {sc!r}; known: {', '.join(SCENARIOS)}"
        for key, (constraint, none_ok) in OPTION_CONSTRAINTS.items():
            value = o.get(key)
            if key in o and not (value is None and none_ok) and not constraint.holds(value):
                problems[key] = f"expected {description(constraint, none_ok)}, got {value!r}"
        _check_instrument(o, problems)
        _check_world(o, problems)
        return problems

    # -- gymnasium API --------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self._closed = False  # a reset opens a closed env again (stable-baselines3's checker does)
        super().reset(seed=seed)
        kind = (options or {}).get("trajectory", self.trajectory_kind)
        if kind is not None and kind not in KINDS:
            raise EnvOptionError(
                f"options['trajectory'] must be one of {', '.join(KINDS)}, got {kind!r}"
            )
        posture = (options or {}).get("posture", self.posture)
        # a fifth stream for the temperature sensor: the first four are what they always were
        truth_rng, traj_rng, noise_rng, start_rng, sensor_rng = self.np_random.spawn(5)
        self.truth = draw_truth(self.scenario, self.nominal, truth_rng, self.overrides)
        self.trajectory, q0 = sample_trajectory(
            self.nominal,
            traj_rng,
            kind,
            duration=self.episode_steps * self.dt,
            v_max=self.task.v_max,
            posture=posture,
        )
        n_ref = self.episode_steps + self.task.preview_steps + 1
        self.references = self.trajectory.positions(np.arange(n_ref) * self.dt)
        plant = self.plant
        plant.configure(self.truth.true_robot, self.truth.hidden)
        plant.place(q0, dirs=start_rng.choice((-1.0, 1.0), 6))
        self.tracker.reset(noise_rng)
        self.truth.bind(_live_conditions(self, self.truth))
        self._temperature = self.thermometer.reset(sensor_rng, plant.temperature)
        self._payload = self.truth.declared_payload_at(plant.time)
        self._k = 0
        self._diverged = False
        self._a1[:] = 0.0
        self._a2[:] = 0.0
        self._obs[:] = 0.0
        self._obs[self._sl["meas_age"]] = MAX_MEASUREMENT_AGE
        self._meas_time = math.nan
        self._meas_points = []
        tool = plant.tool_point()
        self._tool_trail = [tool] if self.render_mode is not None else []
        err_mm = self._error_mm(tool)
        self._fill_obs(None)
        info = self._info(tool, err_mm, None, 0.0, 0.0)
        return self._obs.astype(np.float32), info

    def step(self, action):
        self._check_open("step")
        if self.trajectory is None:  # gym.make's wrapper says so too; the bare env must as well
            raise EnvStateError("SixAxisTrack-v0: call reset() before step()")
        a = self._check_action(action)
        if self._diverged:  # stepped past the end: the same terminal transition again
            return self._on_divergence(a)
        np.multiply(a, self._v_max, out=self._a)
        healthy = self.plant.step(self._a)
        self._k += 1
        if not healthy:
            return self._on_divergence(a)
        tool = self.plant.tool_point()
        if self.render_mode is not None:
            self._tool_trail.append(tool)
        err_mm = self._error_mm(tool)
        self._temperature = self.thermometer.read(self.plant.temperature, self.dt)
        self._payload = self._episode_truth().declared_payload_at(self.plant.time)
        meas = self._measure(tool)
        self._fill_obs(meas)
        reward, parts = self._get_rew(err_mm, a)
        self._a2, self._a1 = self._a1, self._a2
        self._a1[:] = a
        info = self._info(tool, err_mm, meas, parts["reward_tracking"], parts["reward_jerk"])
        return self._obs.astype(np.float32), reward, False, False, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        self._check_open("render")
        if self.trajectory is None:
            raise EnvStateError("SixAxisTrack-v0: call reset() before render()")
        if self._renderer is None:
            self.plant.model.vis.quality.offsamples = 0  # no multisampling: software GL is slow
            vis = self.plant.model.vis.global_  # an offscreen buffer as large as the frame
            vis.offwidth, vis.offheight = (
                max(vis.offwidth, self.width),
                max(vis.offheight, self.height),
            )
            try:
                with warnings.catch_warnings():  # GLFW warns before it fails: one message
                    warnings.simplefilter("ignore")
                    self._renderer = mujoco.Renderer(self.plant.model, self.height, self.width)
            except Exception as exc:  # no GL context: the backend's own error, of any type
                backend = os.environ.get("MUJOCO_GL", "")
                raise SimulatorError(
                    f"SixAxisTrack-v0: MuJoCo cannot render offscreen with MUJOCO_GL={backend!r} "
                    f"({type(exc).__name__}: {exc}); try MUJOCO_GL=egl, or osmesa where EGL is "
                    "missing"
                ) from None
            cam = mujoco.MjvCamera()
            cam.type = mujoco.mjtCamera.mjCAMERA_FREE
            cam.distance = 1.45
            cam.azimuth = 150.0
            cam.elevation = -18.0
            self._camera = cam
        cam, path = self._camera, self.trajectory
        if cam is not None and path is not None and self._camera_target is not path:
            # a new path: look between it and the base
            cam.lookat[:] = 0.6 * path.centre + np.array([0.0, 0.0, 0.15])
            self._camera_target = path
        r = self._renderer
        r.update_scene(self.plant.data, camera=self._camera)
        scn = r.scene
        scn.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        self._draw_overlays(scn)
        return r.render()

    def close(self) -> None:
        """Release the renderer; the env cannot be stepped or rendered afterwards until a new
        ``reset`` (a closed env handing out transitions would hide a use-after-close bug).
        Closing twice is fine."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self._closed = True

    def _check_open(self, what: str) -> None:
        if self._closed:
            raise EnvStateError(
                f"SixAxisTrack-v0: {what}() after close(); reset() it first, or make a new env"
            )

    # -- parts ----------------------------------------------------------------------------------
    def _check_action(self, action) -> np.ndarray:
        """The action as a new float array clipped to [-1, 1]; a clear error when it is not 6
        finite numbers."""
        if type(action) is not np.ndarray:
            try:
                action = np.asarray(action, dtype=float)
            except (TypeError, ValueError) as exc:
                raise ActionError(f"action must be 6 numbers, got {action!r}") from exc
        if action.shape != (6,):
            raise ActionError(f"action must have shape (6,), got shape {action.shape}")
        try:
            finite = math.isfinite(action.sum(dtype=float))  # NaN and inf propagate
            a = np.minimum(action, 1.0, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ActionError(f"action must be 6 numbers, got {action!r}") from exc
        if not finite:
            bad = np.flatnonzero(~np.isfinite(np.asarray(action, dtype=float))).tolist()
            if bad:
                raise ActionError(f"action has NaN or inf at index {bad}: {action}")
        np.maximum(a, -1.0, out=a)
        return a

    def _episode_truth(self) -> EpisodeTruth:
        if self.truth is None:
            raise EnvStateError("SixAxisTrack-v0: call reset() before step()")
        return self.truth

    def _path(self) -> Trajectory:
        if self.trajectory is None:
            raise EnvStateError("SixAxisTrack-v0: call reset() before step()")
        return self.trajectory

    def _reference(self, k: int) -> np.ndarray:
        need = k + self.task.preview_steps + 1
        if need > len(self.references):  # past the planned horizon: extend the path
            n = max(need, 2 * len(self.references))
            self.references = self._path().positions(np.arange(n) * self.dt)
        return self.references[k]

    def _error_mm(self, tool: np.ndarray) -> float:
        d = tool - self._reference(self._k)
        return 1e3 * math.sqrt(float(d @ d))

    def _measure(self, tool: np.ndarray):
        tr = self.tracker
        k = self._k
        if tr.due(k):
            p = self.plant
            # the columns as the controller has them: the sensor's reading, the declared payload
            cols = {"t": p.time, "temperature": self._temperature, "payload": self._payload}
            for i in range(6):
                cols[f"dir{i + 1}"] = float(p.dirs[i])
            tr.sample(k, p.time, tool, p.data.qpos[p.iq], cols)
        return tr.deliver(k) if tr.pending else None

    def _fill_obs(self, meas) -> None:
        o, sl, p = self._obs, self._sl, self.plant
        k = self._k
        d = p.data
        o[self._q_sl] = d.qpos[p.iq] if p.q_view is None else p.q_view
        o[self._qd_sl] = d.qvel[p.iv] if p.qd_view is None else p.qd_view
        o[self._ref_sl] = self.references[k]
        if self._P:
            o[self._prev_sl] = self.references[k + 1 : k + 1 + self._P].reshape(-1)
        if meas is not None:
            o[sl["meas"]] = meas.xyz
            self._meas_time = meas.time
            self._meas_points.append(meas.xyz)
            o[self._valid_i] = 1.0
        else:
            o[self._valid_i] = 0.0
        age = d.time - self._meas_time
        o[self._age_i] = MAX_MEASUREMENT_AGE if not age <= MAX_MEASUREMENT_AGE else age
        o[self._temp_i] = self._temperature
        o[self._payload_i] = self._payload

    def _conditions(self) -> dict[str, float]:
        """The plant's exact temperature and payload now (``truth.conditions()``, for oracles)."""
        return {"temperature": float(self.plant.temperature), "payload": float(self.plant.payload)}

    def _get_rew(self, err_mm: float, action: np.ndarray) -> tuple[float, dict[str, float]]:
        """The reward and its parts: minus the true tracking error (mm) and the jerk penalty
        (the squared second difference of the normalised command)."""
        j = self._j
        np.subtract(action, self._a1, out=j)
        j -= self._a1
        j += self._a2
        jerk = -self.jerk_weight * float(j @ j)
        tracking = -err_mm
        return tracking + jerk, {"reward_tracking": tracking, "reward_jerk": jerk}

    def _info(self, tool, err_mm, meas, r_track, r_jerk) -> dict[str, Any]:
        p = self.plant
        info = {
            "true_error_mm": err_mm,
            "true_tool": tool,
            "reference": self.references[self._k].copy(),
            "measurement_valid": meas is not None,
            "reward_tracking": r_track,
            "reward_jerk": r_jerk,
            "diverged": False,
            "time": p.time,
            "temperature": p.temperature,
            "payload": p.payload,
            "trajectory": self._path().kind,
        }
        if meas is not None:
            info["measurement"] = meas.xyz.copy()
            info["measurement_q"] = meas.q.copy()
            info["measurement_time"] = meas.time
            info["measurement_columns"] = dict(meas.columns)
        return info

    def _on_divergence(self, action: np.ndarray):
        """End the episode with a flag instead of crashing; the last good observation is kept."""
        self._diverged = True
        tool = np.full(3, np.nan)
        info = self._info(tool, math.nan, None, DIVERGENCE_REWARD, 0.0)
        info["diverged"] = True
        mujoco.mj_resetData(self.plant.model, self.plant.data)
        return self._obs.astype(np.float32), DIVERGENCE_REWARD, True, False, info

    def _draw_overlays(self, scn: mujoco.MjvScene) -> None:
        """The reference path (green), the reference now (large green), the measured points
        (red) and the true tool point's path of the last 3 s and where it is now (blue) as extra
        scene geoms."""
        eye = np.eye(3).reshape(-1)

        def add(kind, size, pos, rgba):
            if scn.ngeom >= scn.maxgeom:
                return None
            g = scn.geoms[scn.ngeom]
            mujoco.mjv_initGeom(g, kind, np.asarray(size, float), np.asarray(pos, float), eye, rgba)
            g.emission = 0.4
            scn.ngeom += 1
            return g

        path = self.references[: self.episode_steps + 1 : 2]
        green = np.array([0.05, 0.7, 0.2, 1.0], dtype=np.float32)
        for a, b in itertools.pairwise(path):
            g = add(mujoco.mjtGeom.mjGEOM_CAPSULE, (0.003, 0, 0), a, green)
            if g is not None:
                mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_CAPSULE, 0.003, a, b)
        add(mujoco.mjtGeom.mjGEOM_SPHERE, (0.012, 0, 0), self.references[self._k], green)
        red = np.array([0.85, 0.05, 0.05, 1.0], dtype=np.float32)
        for pt in self._meas_points[-25:]:
            add(mujoco.mjtGeom.mjGEOM_SPHERE, (0.005, 0, 0), pt, red)
        # the true tool point's path over the last 3 s, and where it is now
        blue = np.array([0.1, 0.3, 0.95, 1.0], dtype=np.float32)
        trail = self._tool_trail[-151:]
        for a, b in itertools.pairwise(trail[::-2][::-1]):
            g = add(mujoco.mjtGeom.mjGEOM_CAPSULE, (0.0025, 0, 0), a, blue)
            if g is not None:
                mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_CAPSULE, 0.0025, a, b)
        if trail:
            add(mujoco.mjtGeom.mjGEOM_SPHERE, (0.008, 0, 0), trail[-1], blue)


make_env.env_class = SixAxisTrackEnv  # type: ignore[attr-defined]


def _live_conditions(env: SixAxisTrackEnv, truth: EpisodeTruth) -> Callable[[], dict[str, float]]:
    """The env's live conditions for its episode's truth, holding the env weakly: a bound
    method would make env -> truth -> env a cycle that only the cyclic collector frees, and a
    sweep's worker makes envs faster than it runs (about 16 MiB of MuJoCo state each). Once the
    env is gone the truth has no plant: its episode's start values, as an unbound truth gives."""
    ref = weakref.ref(env)
    start = {
        "temperature": float(truth.hidden.temperature0),
        "payload": float(truth.true_robot.payload),
    }

    def live() -> dict[str, float]:
        e = ref()
        return dict(start) if e is None else e._conditions()

    return live
