"""sixaxis-track's simulated world: the MuJoCo plant, the scenarios that hide physical effects in
it, the laser tracker, the reference trajectories and the Gymnasium environment.

``SixAxisTrack-v0`` is registered here by an entry-point string, so importing ``envs`` loads no
MuJoCo until the environment is made. The arm model these build on is the package ``arm``.

Its episode is as long as its ``episode_seconds`` (10 s, 500 steps, by default): ``gym.make``
builds it in a ``TimeLimit`` of exactly that many steps (``envs.sixaxis_track_v0.make_env``), so
``gym.make("SixAxisTrack-v0", episode_seconds=20)`` runs 1,000 steps, where a fixed registered
limit of 500 cut it in half without a word. ``max_episode_steps`` given to ``gym.make`` can only
shorten it.
"""

from gymnasium.envs.registration import register, registry

__all__ = ["SixAxisTrackEnv"]

if "SixAxisTrack-v0" not in registry:
    register(
        id="SixAxisTrack-v0",
        entry_point="envs.sixaxis_track_v0:make_env",
        max_episode_steps=None,  # the env's own TimeLimit: its episode_seconds
    )


def __getattr__(name: str):
    """``envs.SixAxisTrackEnv`` imports the environment (and MuJoCo) only when asked for."""
    if name == "SixAxisTrackEnv":
        from envs.sixaxis_track_v0 import SixAxisTrackEnv

        return SixAxisTrackEnv
    raise AttributeError(f"module 'envs' has no attribute {name!r}")
