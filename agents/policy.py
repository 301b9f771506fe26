"""Learned policies as agents: what the policy observes, what its action means, and its network
weights in a file that loads without unpickling.

Four variants share one pipeline (:class:`PolicyIO`, a pure function of the env's observation
and info stream, so the same code runs in training and in evaluation):

* ``residual`` (residual RL, Johannink et al. 2019): the base is the ``feedforward`` reference
  (:class:`~agents.reference.FeedforwardAgent`: nominal resolved-rate tracking of the reference
  minus the last measured model error). The policy's action (3) in [-1, 1] moves the base's target
  by up to ``offset_mm`` (0.5 mm) more; a zero action is the base itself.
* ``tool`` (the plain ``ppo``): the operational-space interface of
  :class:`envs.wrappers.ToolDisplacement`, exactly as ``gym.make(..., interface="tool")`` gives it:
  the action (3) is a tool displacement of up to ``tool_step_mm`` per step, mapped through the
  nominal model's damped pseudo-inverse; the observation is the tracking error, the preview
  relative to the reference, the last measured model error and its age and the previous action,
  in mm. No base controller: what the policy does, it learned.
  With ``observe`` (``"joints"``, ``"payload"``, ``"temperature"``, as ``gym.make(...,
  interface="tool", observe=[...])`` gives them) it also sees the encoders' angles and velocities,
  the declared payload and the temperature sensor's reading, in the env's units, scaled by the
  interface's declared fixed scales (``ToolDisplacement.feature_offset``/``feature_scale``).
* ``plain``: the policy's action is the env's action, normalised joint velocities (6); the plain
  ``ppo`` was trained on it before the tool interface (and tracked at 6-7 mm).
* ``joint``: the env's own interface as it is: the raw observation in, the env's action out (a
  stable-baselines3 policy trained on ``gym.make("SixAxisTrack-v0")`` itself, :func:`from_sb3`).

What the residual policy observes (mm where lengths): the encoders (angles, velocities), the
base's last command and the joints' last directions of motion, the joint velocities the path asks
for a few steps ahead (where a joint will reverse and its backlash flip), the model error ``e``
the base feeds forward, how the last measurement changed it and the errors of the three measurements before
(relative to ``e``: their spread is the tracker's noise), the time since the last measurement,
the base's target error ``(r - e) - x_nom(q)``, the previewed path relative to the reference,
the nominal Jacobian (mm/mrad: how each joint's slack or backlash moves the tool) and its columns
for the joints whose direction changed since the last measurement or that the path will reverse
(where backlash moves the tool before any measurement shows it), the previous action, the declared payload and the temperature.
The plain policy observes the encoders, the nominal tool point ``x_nom(q)`` and the reference and
preview minus it (the env's :class:`~envs.wrappers.NominalToolObservation` option), the error's
gradient in joint space ``J_nom(q)^T (r - x_nom(q))`` (which way each joint closes the error, as a
Jacobian-transpose controller feeds back: without it, a plain PPO policy was worse than ``hold`` on
four held-out paths in twenty, up to 6x; with it, no policy of three on any), the last measured
model error and its age, the previous action and the declared payload. Not the temperature: a plain
policy tracks to tens of millimetres, where the arm's thermal growth (a few tenths) is nothing, and
with the feature a trained policy flailed as badly as ``hold`` on a thermal episode it tracked at
37 mm with the sensor reading 20 degC.

A shipped policy is two files in ``agents/policies/``: ``<name>.npz`` (the actor's weights as
arrays named by the network's parameters, and the observation normalisation: read with
``numpy.load(allow_pickle=False)``) and ``<name>.json`` (algorithm, variant, network
architecture, training config, the leaderboard evaluation). The weights are loaded into the
stable-baselines3 network that the architecture describes; nothing is unpickled, so a policy file
from a stranger cannot run code. A stable-baselines3 ``.zip`` (which unpickles) is refused.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import time
import typing
import zipfile
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import numpy as np

from agents.base import Agent, refuse_settings, solve_time_stats
from agents.errors import AgentStateError, PolicyFileError, TrainConfigError
from agents.reference import FeedforwardAgent
from arm.constraints import POSITIVE, Constraint, OneOf
from arm.files import check_input_file, read_input_text
from envs.errors import EnvOptionError
from envs.task import Observation, TaskInfo, Truth
from envs.wrappers import ToolDisplacement, observed

__all__ = [
    "ALGOS",
    "MAX_NETWORK_PARAMETERS",
    "POLICY_DIR",
    "VARIANTS",
    "Algo",
    "PolicyAgent",
    "PolicyFileError",
    "PolicyIO",
    "PolicyNetwork",
    "Variant",
    "check_policy_description",
    "load_policy_file",
    "save_policy_file",
    "shipped_policies",
]

log = logging.getLogger(__name__)

POLICY_DIR = Path(__file__).resolve().parent / "policies"
Variant = Literal["residual", "plain", "tool", "joint"]
Algo = Literal["ppo", "sac", "td3"]
VARIANTS: tuple[str, ...] = typing.get_args(Variant)
ALGOS: tuple[str, ...] = typing.get_args(Algo)
MM = 1e3
#: what the policy's interface takes (:mod:`arm.constraints`): its variant, the residual's reach
#: and the tool variant's step, in mm
POLICY_SETTINGS: dict[str, Constraint] = {
    "variant": OneOf(VARIANTS),
    "offset_mm": POSITIVE,
    "tool_step_mm": POSITIVE,
}
#: preview steps the residual policy sees (relative to the reference now)
RESIDUAL_PREVIEW = (0, 1, 2, 4, 9)
#: preview steps at which the residual policy sees the joint velocities the path asks for
#: (J^+ of the path's velocity there, with the Jacobian of now): where a joint will reverse
PATH_JOINT_VELOCITY = (2, 6)
#: measurements before the last one that the residual policy sees
ERROR_HISTORY = 3
#: activation functions a policy file may name (no class paths: a file is data, not code)
ACTIVATIONS = ("tanh", "relu", "elu", "leaky_relu")


# --------------------------------------------------------------------------------------------------
class PolicyIO:
    """The policy's side of SixAxisTrack-v0 for one episode: :meth:`features` of each observation
    (call it once per step, before :meth:`action`), and :meth:`action`, the env's action from the
    policy's."""

    def __init__(
        self,
        variant: str = "residual",
        offset_mm: float = 0.5,
        tool_step_mm: float = 5.0,
        observe: tuple[str, ...] | list[str] = (),
    ) -> None:
        refuse_settings(
            POLICY_SETTINGS, variant=variant, offset_mm=offset_mm, tool_step_mm=tool_step_mm
        )
        if observe and variant != "tool":
            raise PolicyFileError(f"observe is for the tool variant, not {variant!r}")
        self.variant = variant
        self.offset_mm = float(offset_mm)
        self.tool_step_mm = float(tool_step_mm)
        self.observe = observed(observe)
        self.base = FeedforwardAgent()
        self.task: TaskInfo | None = None
        self.tool: ToolDisplacement | None = None

    @property
    def action_size(self) -> int:
        return 6 if self.variant in ("plain", "joint") else 3

    def observation_size(self, task: TaskInfo) -> int:
        P = int(task.preview_steps)
        if self.variant == "tool":
            return ToolDisplacement(task, self.tool_step_mm, observe=self.observe).obs_size
        if self.variant == "joint":
            return int(task.obs_size)
        if self.variant == "residual":
            return (
                6 * 4
                + 6 * len(PATH_JOINT_VELOCITY)
                + 3
                + 3
                + 3 * ERROR_HISTORY
                + 1
                + 3
                + 3 * len(RESIDUAL_PREVIEW)
                + 18 * 3
                + 3
                + 2
            )
        return 6 + 6 + 3 + 3 + 6 + 3 * P + 3 + 1 + 6 + 1

    def reset(self, task: TaskInfo) -> None:
        self.task = task
        if self.variant == "tool":
            self.tool = ToolDisplacement(task, self.tool_step_mm, observe=self.observe)
        else:
            self.base.reset(task)
        self._start_phase()

    def next_phase(self, task: TaskInfo) -> None:
        self.task = task
        if self.tool is not None:  # the tool interface keeps its model error, as feedforward does
            error, error_time = self.tool.error, self.tool.error_time
            self.tool = ToolDisplacement(task, self.tool_step_mm, observe=self.observe)
            self.tool.error, self.tool.error_time = error, error_time
        else:
            self.base.next_phase(task)
        self._start_phase()

    def _start_phase(self) -> None:
        self.prev_action = np.zeros(self.action_size)
        self.history: deque[np.ndarray] = deque(maxlen=ERROR_HISTORY + 1)
        self._o: Observation | None = None
        self._info: Mapping[str, Any] = {}

    def features(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        task = self.task
        if task is None:
            raise AgentStateError("PolicyIO.features before reset(): no task yet")
        if self.tool is not None:  # the operational-space interface: envs.wrappers's numbers
            return self.tool.clipped(self.tool.observe(obs, info))
        if self.variant == "joint":  # the env's own observation, as an SB3 policy of it sees it
            return np.array(obs, dtype=np.float64)
        o = Observation.parse(task, obs)
        self._o, self._info = o, info
        base = self.base
        if base.observe(o, info):
            self.history.append(base.error.copy())
        t = info.get("time")
        age = (float(t) - base.last_measurement_time) if t is not None else o.meas_age
        age = float(min(age, 1.0)) if np.isfinite(age) else 1.0
        payload = 0.0 if o.payload is None else float(o.payload)
        if self.variant == "residual":
            x, J = base.point_dq(o.q)
            e = base.error
            past = list(self.history)[:-1][::-1]  # the measurements before the last, newest first
            hist = np.zeros((ERROR_HISTORY, 3))
            for k, h in enumerate(past):
                hist[k] = h - e
            refs = o.references(max(max(RESIDUAL_PREVIEW), max(PATH_JOINT_VELOCITY) + 1) + 1)
            pv = refs[list(RESIDUAL_PREVIEW)] - o.ref
            v_max = np.asarray(task.v_max, dtype=float)
            jj = J @ J.T + (base.damping**2) * np.eye(3)
            path_v = [
                J.T @ np.linalg.solve(jj, (refs[k + 1] - refs[k]) / float(task.dt)) / v_max
                for k in PATH_JOINT_VELOCITY
            ]
            ahead = path_v[-1]
            # the direction each joint will move in (its present one where the path barely moves it)
            reverse = np.where(np.abs(ahead) > 1e-3, np.sign(ahead), base.dirs)
            f = np.concatenate(
                [
                    o.q,
                    o.qd,
                    base.v_prev / v_max,
                    base.dirs,
                    *path_v,
                    e * MM,
                    base.error_change * MM,
                    hist.reshape(-1) * MM,
                    [age],
                    ((o.ref - e) - x) * MM,
                    pv.reshape(-1) * MM,
                    J.reshape(-1),  # m/rad = mm/mrad
                    # per joint: how the tool moves (mm per mrad) for the joints whose direction
                    # changed since the last measurement, and for those the path will reverse
                    (J * (base.dirs - base.measured_dirs) / 2.0).T.reshape(-1),
                    (J * (reverse - base.dirs) / 2.0).T.reshape(-1),
                    self.prev_action,
                    [payload, o.temperature - 20.0],
                ]
            )
        else:
            x, J = base.point_dq(o.q)
            pv = o.references(int(task.preview_steps)) - x
            f = np.concatenate(
                [
                    o.q,
                    o.qd,
                    x,
                    (o.ref - x) * MM,
                    J.T @ (o.ref - x) * MM,  # mm * m/rad: which way each joint closes the error
                    pv.reshape(-1) * MM,
                    base.error * MM,
                    [age],
                    self.prev_action,
                    [payload],
                ]
            )
        return f.astype(np.float64)

    def action(self, a: np.ndarray) -> np.ndarray:
        """The env's action (6,) for the policy's action ``a`` at the last observation."""
        if self.tool is not None:
            self.prev_action = np.clip(np.asarray(a, dtype=float).reshape(-1), -1.0, 1.0)
            return self.tool.command(a)
        if self.variant == "joint":
            self.prev_action = np.clip(np.asarray(a, dtype=float).reshape(-1), -1.0, 1.0)
            return self.prev_action
        if self._o is None:
            raise AgentStateError("PolicyIO.action before features(): no observation yet")
        a = np.clip(np.asarray(a, dtype=float).reshape(-1), -1.0, 1.0)
        self.prev_action = a
        if self.variant == "plain":
            return a
        offset = -self.base.error + a * (self.offset_mm / MM)
        return self.base.track(self._o, self._info, offset)


# --------------------------------------------------------------------------------------------------
def _activation(name: str) -> Any:
    import torch.nn as nn

    table = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU, "leaky_relu": nn.LeakyReLU}
    try:
        return table[name]
    except KeyError:
        raise PolicyFileError(
            f"activation_fn {name!r} is not one of {', '.join(ACTIVATIONS)}"
        ) from None


def policy_kwargs_for_sb3(kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """A policy's architecture as data (JSON/TOML: the activation by name) into the keyword
    arguments of stable-baselines3's policy classes (``structured`` chooses the class,
    :func:`policy_class`, and is not one of them)."""
    out = dict(kwargs)
    out.pop("structured", None)
    if "activation_fn" in out:
        out["activation_fn"] = _activation(str(out["activation_fn"]))
    if isinstance(out.get("net_arch"), Mapping):
        out["net_arch"] = {k: list(v) for k, v in out["net_arch"].items()}
    elif "net_arch" in out:
        out["net_arch"] = list(out["net_arch"])
    return out


def policy_class(algo: str, kwargs: Mapping[str, Any]) -> Any:
    """The stable-baselines3 policy of ``kwargs``: ``"MlpPolicy"``, or for PPO with
    ``structured = true`` the structured control net (:mod:`agents.structured`)."""
    if kwargs.get("structured"):
        if algo != "ppo":
            raise TrainConfigError(f"structured is a PPO network; {algo} has none")
        from agents.structured import StructuredActorCriticPolicy

        return StructuredActorCriticPolicy
    return "MlpPolicy"


def build_network(
    algo: str, obs_size: int, act_size: int, policy_kwargs: Mapping[str, Any], use_sde: bool
) -> Any:
    """An untrained stable-baselines3 policy of the given architecture (torch, CPU)."""
    import gymnasium as gym
    import torch

    torch.set_num_threads(1)
    obs_space = gym.spaces.Box(-np.inf, np.inf, (obs_size,), np.float32)
    act_space = gym.spaces.Box(-1.0, 1.0, (act_size,), np.float32)
    kw = policy_kwargs_for_sb3(policy_kwargs)
    if algo == "ppo":
        from stable_baselines3.common.policies import ActorCriticPolicy

        cls = policy_class(algo, policy_kwargs)
        cls = ActorCriticPolicy if cls == "MlpPolicy" else cls
        return cls(obs_space, act_space, lambda _: 0.0, use_sde=use_sde, **kw)
    if algo == "sac":
        from stable_baselines3.sac.policies import SACPolicy

        return SACPolicy(obs_space, act_space, lambda _: 0.0, use_sde=use_sde, **kw)
    if algo == "td3":
        from stable_baselines3.td3.policies import TD3Policy

        return TD3Policy(obs_space, act_space, lambda _: 0.0, **kw)
    raise PolicyFileError(f"unknown algorithm {algo!r}; choose {', '.join(ALGOS)}")


def acting_module(algo: str, policy: Any) -> Any:
    """The part of an SB3 policy that acts (PPO: the whole actor-critic; SAC, TD3: the actor)."""
    return policy if algo == "ppo" else policy.actor


class PolicyNetwork:
    """A policy's network with its observation normalisation: ``act(features)`` is the
    deterministic action in [-1, 1].

    It infers in float64 (the weights cast, the features never rounded to float32), whatever
    precision it was trained in: float32 kernels round differently on CPUs with other vector units
    (AVX2, AVX-512) or another BLAS, and a closed loop carries a 1e-7 difference on to the
    metrics. In float64 the differences between machines are about 1e-16, far below the
    ``--rtol 1e-6`` that ``sixaxis reproduce`` promises (tests/test_policy_reproducibility.py
    perturbs every shipped policy's observations to keep that promise)."""

    def __init__(self, algo: str, policy: Any, norm: Mapping[str, Any]) -> None:
        self.algo = algo
        self.policy = policy
        from agents.structured import StructuredActorCriticPolicy  # SB3 is loaded: policy is one

        self.structured = isinstance(policy, StructuredActorCriticPolicy)
        # a float64 snapshot of the weights: a policy still in training keeps its own float32 ones
        self.params = {
            k: v.detach().to(dtype=_float64()).clone()
            for k, v in acting_module(algo, policy).state_dict().items()
        }
        self.mean = np.asarray(norm["obs_mean"], dtype=float)
        self.var = np.asarray(norm["obs_var"], dtype=float)
        self.clip = float(norm["obs_clip"])
        self.eps = float(norm["obs_epsilon"])

    def act(self, features: np.ndarray) -> np.ndarray:
        import torch

        x = np.clip((features - self.mean) / np.sqrt(self.var + self.eps), -self.clip, self.clip)
        with torch.no_grad():
            a = self._deterministic_action(torch.as_tensor(x, dtype=torch.float64).reshape(1, -1))
        return np.clip(a.numpy().reshape(-1), -1.0, 1.0)

    def _deterministic_action(self, x: Any) -> Any:
        """The distribution's mode, through the acting layers themselves: stable-baselines3's
        ``predict`` would cast the observation to float32 (``preprocess_obs``). PPO: the actor's
        latent, its mean action (tanh where the policy squashes); SAC: tanh of the mean; TD3:
        its actor (ending in tanh). The features extractor of a flat Box is the identity."""
        import torch

        call = self._layer
        if self.algo == "ppo":
            latent = call("mlp_extractor.policy_net", x)
            if self.structured:  # agents.structured: the features beside the MLP's latent
                latent = torch.cat([x, latent], dim=-1)
            a = call("action_net", latent)
            return torch.tanh(a) if self.policy.squash_output else a
        if self.algo == "sac":
            return torch.tanh(call("mu", call("latent_pi", x)))
        return call("mu", x)

    def _layer(self, name: str, x: Any) -> Any:
        """The acting module's layer ``name`` applied to ``x`` with the float64 weights."""
        from torch.func import functional_call

        layer = acting_module(self.algo, self.policy).get_submodule(name)
        prefix = name + "."
        params = {k[len(prefix) :]: v for k, v in self.params.items() if k.startswith(prefix)}
        return functional_call(layer, params, (x,))


def _float64() -> Any:
    import torch

    return torch.float64


def save_policy_file(
    path: str | Path,
    algo: str,
    policy: Any,
    norm: Mapping[str, Any],
    meta: Mapping[str, Any],
) -> Path:
    """Write ``path`` (.npz: the acting network's weights and the observation normalisation) and
    its ``.json`` description, both atomically. ``meta`` needs ``variant``, ``obs_size``,
    ``act_size``, ``policy_kwargs`` (as data), ``use_sde`` and ``offset_mm``."""
    from arm.files import atomic_path, atomic_write_text

    path = Path(path)
    if path.suffix != ".npz":
        raise PolicyFileError(f"{path}: a policy file ends in .npz")
    arrays = {
        f"weights/{k}": v.detach().cpu().numpy()
        for k, v in acting_module(algo, policy).state_dict().items()
    }
    for k in ("obs_mean", "obs_var"):
        arrays[k] = np.asarray(norm[k], dtype=np.float64)
    arrays["obs_clip"] = np.asarray(float(norm["obs_clip"]))
    arrays["obs_epsilon"] = np.asarray(float(norm["obs_epsilon"]))
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    doc = {"format": "sixaxis-policy/1", "algo": algo, **meta}
    atomic_write_text(path.with_suffix(".json"), json.dumps(doc, indent=2) + "\n")
    return path


def load_policy_file(path: str | Path) -> tuple[PolicyNetwork, dict[str, Any]]:
    """The network and description of a policy file (``.npz`` with its ``.json``), loaded without
    unpickling; anything else (a stable-baselines3 ``.zip``, a pickle) is refused."""
    path = Path(path)
    if path.suffix != ".npz":
        raise PolicyFileError(
            f"{path}: refusing to load a policy that is not a .npz weight file (a "
            f"stable-baselines3 .zip or a pickle would run code when loaded); export it with "
            "`sixaxis train export`"
        )
    meta_path = path.with_suffix(".json")
    check_input_file(path, "policy file", "weights", PolicyFileError)  # a FIFO would hang
    if not os.path.exists(meta_path):
        raise PolicyFileError(f"{path}: its description {meta_path.name} is missing")
    text = read_input_text(meta_path, "policy description", "json", PolicyFileError)
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PolicyFileError(f"{meta_path}: not valid JSON: {exc}") from None
    except RecursionError:
        raise PolicyFileError(f"{meta_path}: JSON nested too deeply to read") from None
    check_policy_description(meta, str(meta_path))
    algo = meta["algo"]
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (ValueError, OSError, zipfile.BadZipFile) as exc:  # object arrays, a foreign file
        raise PolicyFileError(f"{path}: not a policy weight file ({exc})") from exc
    foreign = sorted(k for k, v in arrays.items() if not isinstance(v, np.ndarray))
    if foreign:
        raise PolicyFileError(f"{path}: not a policy weight file (members {foreign[:3]})")
    import torch

    policy = build_network(
        algo,
        int(meta["obs_size"]),
        int(meta["act_size"]),
        meta["policy_kwargs"],
        bool(meta.get("use_sde", False)),
    )
    module = acting_module(algo, policy)
    expected = module.state_dict()
    given = {k[len("weights/") :]: v for k, v in arrays.items() if k.startswith("weights/")}
    missing = sorted(set(expected) - set(given))
    extra = sorted(set(given) - set(expected))
    if missing or extra:
        raise PolicyFileError(
            f"{path}: the weights do not fit the network of {meta_path.name} "
            f"(missing {missing[:3]}, unexpected {extra[:3]})"
        )
    state = {}
    for k, want in expected.items():
        v = given[k]
        if tuple(v.shape) != tuple(want.shape) or v.dtype.kind != "f":
            raise PolicyFileError(
                f"{path}: weight {k!r} has shape {v.shape} ({v.dtype}), the network needs "
                f"{tuple(want.shape)}"
            )
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise PolicyFileError(
                f"{path}: weight {k!r} has {bad.size} NaN or infinite value(s) (the first at "
                f"flat index {bad[0]}): not a trained network"
            )
        state[k] = torch.from_numpy(np.array(v, dtype=np.float32))  # as trained; act() casts
    module.load_state_dict(state, strict=True)
    _check_normalisation(arrays, int(meta["obs_size"]), path)
    return PolicyNetwork(algo, policy, arrays), meta


def _check_normalisation(arrays: Mapping[str, np.ndarray], n: int, path: Path) -> None:
    """The observation normalisation ``(x - mean) / sqrt(var + eps)``, clipped to ``clip``: mean
    and var (n,), finite, var >= 0; eps >= 0 with var + eps > 0; clip > 0. Anything else would
    make every action NaN (a torch error mid-episode)."""
    for k in ("obs_mean", "obs_var", "obs_clip", "obs_epsilon"):
        if k not in arrays:
            raise PolicyFileError(f"{path}: missing the observation normalisation {k!r}")
    for k, shape in (("obs_mean", (n,)), ("obs_var", (n,)), ("obs_clip", ()), ("obs_epsilon", ())):
        v = arrays[k]
        if v.shape != shape or v.dtype.kind not in "fiu":
            raise PolicyFileError(
                f"{path}: {k} has shape {v.shape} ({v.dtype}), expected {shape} numbers"
            )
        if not np.all(np.isfinite(v)):
            raise PolicyFileError(f"{path}: {k} holds NaN or infinity")
    var, eps = arrays["obs_var"], float(arrays["obs_epsilon"])
    if np.any(var < 0) or eps < 0:
        i = int(np.flatnonzero(var < 0)[0]) if np.any(var < 0) else None
        where = f"obs_var[{i}] = {var[i]:g}" if i is not None else f"obs_epsilon = {eps:g}"
        raise PolicyFileError(f"{path}: {where} is negative; a variance is not")
    if np.any(var + eps <= 0):
        raise PolicyFileError(f"{path}: obs_var + obs_epsilon is 0: the features cannot be scaled")
    if not float(arrays["obs_clip"]) > 0:
        raise PolicyFileError(f"{path}: obs_clip = {float(arrays['obs_clip']):g} must be > 0")


#: The largest network a policy file may describe, checked before it is built: the shipped ones
#: have about 20,000 parameters; 200,000 units in a layer asked for tens of gigabytes.
MAX_LAYER_UNITS = 4096
MAX_LAYERS = 8
MAX_OBS_SIZE = 10_000
MAX_NETWORK_PARAMETERS = 5_000_000
#: policy keyword arguments a file may give, as data, per algorithm (no classes: a file is data)
POLICY_KWARGS = {
    "ppo": {
        "net_arch",
        "activation_fn",
        "ortho_init",
        "log_std_init",
        "full_std",
        "use_expln",
        "squash_output",
        "share_features_extractor",
        "structured",
    },
    "sac": {
        "net_arch",
        "activation_fn",
        "log_std_init",
        "use_expln",
        "clip_mean",
        "n_critics",
        "share_features_extractor",
    },
    "td3": {"net_arch", "activation_fn", "n_critics", "share_features_extractor"},
}
_BOOL_KWARGS = {
    "ortho_init",
    "full_std",
    "use_expln",
    "squash_output",
    "share_features_extractor",
    "structured",
}
_ARCH_KEYS = {"ppo": ("pi", "vf"), "sac": ("pi", "qf"), "td3": ("pi", "qf")}


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def check_policy_description(meta: Any, where: str) -> None:
    """Refuse a policy description (``.json``) that does not describe a network of this project,
    before anything is built: unknown algorithm, variant or policy keyword argument, sizes that
    are not whole numbers in range (``obs_size`` 1e9), a layer beyond :data:`MAX_LAYER_UNITS`
    or a network beyond :data:`MAX_NETWORK_PARAMETERS`. Raises :class:`PolicyFileError` naming
    ``where`` and the key."""
    if not isinstance(meta, dict):
        raise PolicyFileError(f"{where}: expected a JSON object")
    for key in ("algo", "variant", "obs_size", "act_size", "policy_kwargs"):
        if key not in meta:
            raise PolicyFileError(f"{where}: missing key {key!r}")
    algo, variant = meta["algo"], meta["variant"]
    if algo not in ALGOS:
        raise PolicyFileError(f"{where}: algo {algo!r} is not one of {', '.join(ALGOS)}")
    if variant not in VARIANTS:
        raise PolicyFileError(f"{where}: variant {variant!r} is not one of {', '.join(VARIANTS)}")
    _check_sizes(meta, variant, where)
    kw = meta["policy_kwargs"]
    if not isinstance(kw, dict):
        raise PolicyFileError(f"{where}: policy_kwargs must be an object, got {kw!r}")
    _check_policy_kwargs(algo, kw, where)
    total = network_parameters(algo, kw, meta["obs_size"], meta["act_size"], where)
    if total > MAX_NETWORK_PARAMETERS:
        raise PolicyFileError(
            f"{where}: the network has {total:,} parameters, more than the "
            f"{MAX_NETWORK_PARAMETERS:,} a policy file may describe"
        )


def _check_sizes(meta: dict, variant: str, where: str) -> None:
    obs, act = meta["obs_size"], meta["act_size"]
    if not _is_int(obs) or not 1 <= obs <= MAX_OBS_SIZE:
        raise PolicyFileError(
            f"{where}: obs_size must be a whole number from 1 to {MAX_OBS_SIZE}, got {obs!r}"
        )
    want = 6 if variant in ("plain", "joint") else 3
    if not _is_int(act) or act != want:
        raise PolicyFileError(f"{where}: act_size of a {variant} policy is {want}, got {act!r}")
    offset = meta.get("offset_mm", 0.5)
    if isinstance(offset, bool) or not isinstance(offset, int | float) or not 0 < offset < 1e3:
        raise PolicyFileError(f"{where}: offset_mm must be a positive number of mm, got {offset!r}")
    step = meta.get("tool_step_mm", 5.0)
    if isinstance(step, bool) or not isinstance(step, int | float) or not 0 < step < 1e3:
        raise PolicyFileError(
            f"{where}: tool_step_mm must be a positive number of mm, got {step!r}"
        )
    if not isinstance(meta.get("use_sde", False), bool):
        raise PolicyFileError(f"{where}: use_sde must be true or false, got {meta['use_sde']!r}")
    observe = meta.get("observe", [])
    try:
        observed(observe)
    except EnvOptionError as exc:
        raise PolicyFileError(f"{where}: {exc}") from None
    if observe and variant != "tool":
        raise PolicyFileError(f"{where}: observe is for the tool variant, not {variant!r}")


def _check_policy_kwargs(algo: str, kw: dict, where: str) -> None:
    unknown = sorted(set(kw) - POLICY_KWARGS[algo])
    if unknown:
        raise PolicyFileError(
            f"{where}: policy_kwargs {', '.join(map(repr, unknown))} unknown for {algo}; known: "
            f"{', '.join(sorted(POLICY_KWARGS[algo]))}"
        )
    for k in sorted(_BOOL_KWARGS & set(kw)):
        if not isinstance(kw[k], bool):
            raise PolicyFileError(f"{where}: policy_kwargs.{k} must be true or false")
    for k in ("log_std_init", "clip_mean"):
        v = kw.get(k, 0.0)
        if isinstance(v, bool) or not isinstance(v, int | float) or not abs(v) < 1e3:
            raise PolicyFileError(f"{where}: policy_kwargs.{k} must be a finite number, got {v!r}")
    if "activation_fn" in kw and kw["activation_fn"] not in ACTIVATIONS:
        raise PolicyFileError(
            f"{where}: policy_kwargs.activation_fn {kw['activation_fn']!r} is not one of "
            f"{', '.join(ACTIVATIONS)}"
        )
    critics = kw.get("n_critics", 2)
    if not _is_int(critics) or not 1 <= critics <= 10:
        raise PolicyFileError(f"{where}: policy_kwargs.n_critics must be 1 to 10, got {critics!r}")


def network_parameters(algo: str, kw: dict, obs: int, act: int, where: str) -> int:
    """How many parameters the network of ``net_arch`` has (the actor and its critics), each
    layer checked first: up to :data:`MAX_LAYERS` of at most :data:`MAX_LAYER_UNITS` units."""
    arch = kw.get("net_arch", [64, 64])
    heads = _ARCH_KEYS[algo]
    if isinstance(arch, dict):
        extra = sorted(set(arch) - set(heads))
        if extra:
            raise PolicyFileError(
                f"{where}: policy_kwargs.net_arch keys {extra} unknown; {algo} has {', '.join(heads)}"
            )
        layers = {h: arch.get(h, []) for h in heads}
    else:
        layers = {h: arch for h in heads}
    critics = kw.get("n_critics", 2)
    total = 0
    for head, units in layers.items():
        if (
            not isinstance(units, list)
            or len(units) > MAX_LAYERS
            or not all(_is_int(u) and 1 <= u <= MAX_LAYER_UNITS for u in units)
        ):
            raise PolicyFileError(
                f"{where}: policy_kwargs.net_arch ({head}) must be up to {MAX_LAYERS} layers of 1 "
                f"to {MAX_LAYER_UNITS} units, got {units!r}"
            )
        sizes = [obs, *units, act if head == "pi" else 1]
        if head != "pi" and algo != "ppo":
            sizes[0] = obs + act  # a Q-function reads the action too
        n = sum((a + 1) * b for a, b in itertools.pairwise(sizes))
        if head == "pi" and kw.get("structured"):
            n += obs * act  # agents.structured: the features reach the action
        total += n * (critics if head == "qf" else 1)
    return total


# --------------------------------------------------------------------------------------------------
def shipped_policies() -> list[str]:
    """The names of the policies shipped in ``agents/policies/``."""
    return sorted(p.stem for p in POLICY_DIR.glob("*.npz"))


def _policy_path(policy: str | None, path: str | None) -> Path:
    """The policy file of a shipped ``policy`` name or of a file ``path`` (one of the two)."""
    if policy is not None and path is not None:
        raise PolicyFileError(
            f"policy {policy!r} and path {path!r}: give one, policy (a shipped policy's name) or "
            "path (a policy file); a file goes on the leaderboard as the agent 'policy' with "
            'settings {"path": ...}'
        )
    if path is not None:
        return _file_as_written(str(path))
    if policy is None:
        raise PolicyFileError(
            "give policy (a shipped policy's name: "
            f"{', '.join(shipped_policies()) or 'none shipped'}) or path (a policy file)"
        )
    if "/" in policy or "\\" in policy or policy.endswith(".npz"):
        raise PolicyFileError(
            f"policy {policy!r} names a file: give it as path, to the agent 'policy' "
            f'(`sixaxis evaluate policy --settings \'{{"path": "{policy}"}}\'`); policy is a '
            f"shipped policy's name: {', '.join(shipped_policies()) or 'none shipped'}"
        )
    found = POLICY_DIR / f"{policy}.npz"
    if not os.path.exists(found):
        raise PolicyFileError(
            f"no shipped policy {policy!r} (shipped: {', '.join(shipped_policies()) or 'none'}; "
            "a policy file goes in path); train one with `sixaxis train ppo --config "
            "experiments/configs/ppo-residual.toml --ship`"
        )
    return found


def _file_as_written(path: str) -> Path:
    """``path`` as written if it ends in ``.npz``, else with ``.npz`` added; a file of another
    kind (a stable-baselines3 ``.zip``, a pickle) is refused: loading it would run code."""
    given = Path(path)
    if given.suffix == ".npz":
        return given
    if given.suffix and os.path.exists(given):
        raise PolicyFileError(
            f"path {path!r}: refusing to load a policy that is not a .npz weight file (a "
            "stable-baselines3 .zip or a pickle would run code when loaded); export an SB3 "
            "model with agents.from_sb3"
        )
    return Path(path + ".npz")


class PolicyAgent(Agent):
    """A trained policy as an agent, deterministic: the shipped ``policy`` of
    ``agents/policies/`` by name, or a policy file ``path`` (a ``.npz`` with its ``.json``,
    taken as written, ``.npz`` added if it is not there); one of the two, never both. ``name``
    is how it shows (default: the policy's name, or the file's stem)."""

    def __init__(
        self, policy: str | None = None, path: str | None = None, name: str | None = None
    ) -> None:
        super().__init__()
        self.path = _policy_path(policy, path)
        self.name = name or policy or self.path.stem
        check_input_file(self.path, "policy file", "weights", PolicyFileError)
        self.network: PolicyNetwork | None = None
        self.meta: dict[str, Any] = {}

    @classmethod
    def from_network(
        cls, name: str, network: PolicyNetwork, meta: Mapping[str, Any]
    ) -> PolicyAgent:
        """An agent around a network in memory (training's evaluations)."""
        agent = cls.__new__(cls)
        Agent.__init__(agent)
        agent.name, agent.path = name, Path(f"{name}.npz")
        agent.network, agent.meta = network, dict(meta)
        return agent

    def _load(self) -> None:
        self.network, self.meta = load_policy_file(self.path)

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        if self.network is None:
            self._load()
        self.task = task
        self.io = PolicyIO(
            self.meta["variant"],
            float(self.meta.get("offset_mm", 0.5)),
            float(self.meta.get("tool_step_mm", 5.0)),
            tuple(self.meta.get("observe", ())),
        )
        self.io.reset(task)
        n = self.io.observation_size(task)
        if n != int(self.meta["obs_size"]):
            raise PolicyFileError(
                f"{self.path}: the policy takes {self.meta['obs_size']} features, this env gives "
                f"{n} (another preview length?)"
            )
        self._times: list[float] = []

    def next_phase(self, task: TaskInfo, truth: Truth | None = None) -> None:
        self.task = task
        self.io.next_phase(task)

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        t0 = time.perf_counter()
        assert self.network is not None
        a = self.network.act(self.io.features(obs, info))
        out = self.io.action(a)
        self.last_solve_time = time.perf_counter() - t0
        self._times.append(self.last_solve_time)
        return out

    def report(self) -> dict[str, Any]:
        """Solve times, and the training budget the policy file records (the shipped run's
        steps and wall time, how many seeds were trained to choose it, and which of them was
        shipped: ``training_picked``, ``best`` or ``median``, where the file says)."""
        out: dict[str, Any] = dict(solve_time_stats(self._times))
        training = self.meta.get("training") or {}
        for key, field in (
            ("training_steps", "timesteps"),
            ("training_wall_s", "wall_s"),
            ("training_seeds", "seeds_trained"),
            ("training_wall_s_all_seeds", "wall_s_all_seeds"),
        ):
            value = training.get(field)
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                out[key] = float(value)
        if isinstance(training.get("picked"), str):
            out["training_picked"] = training["picked"]
        return out
