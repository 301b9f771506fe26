"""Controllers and estimators for SixAxisTrack-v0, behind one small interface.

    from agents.registry import make_agent
    from agents.runner import run_episode

    result = run_episode(make_agent("mpc"), {"scenario": "geometric"}, seed=0)
    result.rms_mm(start=3.0)            # tracking RMS after 3 s, mm (true tool point)

Modules: :mod:`agents.base` (the ``Agent`` interface), :mod:`agents.reference` (hold, nominal,
feedforward, calibrated), :mod:`agents.mpc` (kinematic MPC: QP or IPOPT),
:mod:`agents.online_calibration` (recursive least squares that can widen, the tracker buffer),
:mod:`agents.self_diagnosis` (``mpc-diagnose``: the MPC that diagnoses its own model with the
lab), :mod:`agents.tool_model` (the error model in CasADi), :mod:`agents.policy` (learned
policies: features, policy files, the agent), :mod:`agents.training` (stable-baselines3 PPO, SAC,
TD3 training), :mod:`agents.registry`
(agents by name or ``package.module:Class``), :mod:`agents.runner` (the episode loop, phases),
:mod:`agents.adapters` (``agents.from_sb3``: any stable-baselines3 policy as an agent).
Importing this package loads neither MuJoCo nor torch.
"""

from __future__ import annotations

from typing import Any

__all__ = ["from_sb3"]


def __getattr__(name: str) -> Any:
    """``agents.from_sb3``, imported when first used (it needs torch and the env)."""
    if name == "from_sb3":
        from agents.adapters import from_sb3

        return from_sb3
    raise AttributeError(f"module 'agents' has no attribute {name!r}")
