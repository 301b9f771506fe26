"""sixaxis-track's robot and its world.

The pure-numpy parts (description, kinematics, error model, measurement files) import no simulator.
``SixAxisTrack-v0`` is registered here by an entry-point string, so importing ``envs`` loads no
MuJoCo until the environment is made.
"""

from gymnasium.envs.registration import register, registry

from envs.description import RobotDescription, load_robot, seed_robot
from envs.errormodel import ErrorModel
from envs.measurements import MeasurementSet, read_measurements, write_measurements

__all__ = [
    "ErrorModel",
    "MeasurementSet",
    "RobotDescription",
    "SixAxisTrackEnv",
    "load_robot",
    "read_measurements",
    "seed_robot",
    "write_measurements",
]

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
