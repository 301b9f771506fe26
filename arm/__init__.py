"""The arm model: the description of a six-axis arm, its kinematics and inverse kinematics, the
effects that make a real arm differ from its nominal table, the error model that combines them,
and the measurement and pose files.

Pure numpy and scipy: importing ``arm`` loads no simulator (neither MuJoCo nor gymnasium). The
MuJoCo plant and the Gymnasium environment live in ``envs``; the lab and the agents build on this.

    from arm import seed_robot, ErrorModel, read_measurements

    robot = seed_robot()
    model = ErrorModel(robot, "geometric,compliance")
    data = read_measurements("data.csv")
"""

from arm.description import RobotDescription, load_robot, seed_robot
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet, read_measurements, write_measurements

__all__ = [
    "ErrorModel",
    "MeasurementSet",
    "RobotDescription",
    "load_robot",
    "read_measurements",
    "seed_robot",
    "write_measurements",
]
