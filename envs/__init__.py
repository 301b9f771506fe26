"""sixaxis-track's simulated world: the MuJoCo plant, the scenarios that hide physical effects in
it, the laser tracker, the reference trajectories and the Gymnasium environment.

``SixAxisTrack-v0`` is registered here by an entry-point string, so importing ``envs`` loads no
MuJoCo until the environment is made. The arm model these build on is the package ``arm``.
"""

from gymnasium.envs.registration import register, registry

__all__ = ["SixAxisTrackEnv"]

if "SixAxisTrack-v0" not in registry:
    register(
        id="SixAxisTrack-v0",
        entry_point="envs.sixaxis_track_v0:SixAxisTrackEnv",
        max_episode_steps=500,  # 10 s at 50 Hz
    )


def __getattr__(name: str):
    """``envs.SixAxisTrackEnv`` imports the environment (and MuJoCo) only when asked for."""
    if name == "SixAxisTrackEnv":
        from envs.sixaxis_track_v0 import SixAxisTrackEnv

        return SixAxisTrackEnv
    raise AttributeError(f"module 'envs' has no attribute {name!r}")
