"""MuJoCo, loaded once for the simulated world, with a clear error when it cannot start.

On Linux without a display, MuJoCo renders offscreen with EGL unless ``MUJOCO_GL`` says otherwise
(set here, before MuJoCo loads). MuJoCo checks ``MUJOCO_GL`` when it is imported and refuses a
value it does not know (a ``RuntimeError``), or fails to load the backend's library (OSMesa
missing); here either is a :class:`SimulatorError` naming the variable and the values it takes, so every command that simulates (collect, evaluate, render,
sweep) says so in one line. A backend that loads but cannot make a context (no OSMesa, no display
for GLFW) is reported when a frame is first rendered (``SixAxisTrackEnv.render``).
"""

from __future__ import annotations

import os
import sys

from envs.errors import SimulatorError

__all__ = ["GL_BACKENDS", "SimulatorError", "mujoco"]

#: the values of MUJOCO_GL that MuJoCo takes on this platform (besides "disable")
GL_BACKENDS = ("egl", "osmesa", "glfw") if sys.platform.startswith("linux") else ("glfw",)


if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering; set before mujoco loads

try:
    import mujoco
except ImportError:
    raise  # MuJoCo not installed: the environment's problem, said by Python itself
except Exception as exc:  # MUJOCO_GL names a backend MuJoCo does not know, or cannot load
    raise SimulatorError(
        f"MuJoCo cannot start with MUJOCO_GL={os.environ.get('MUJOCO_GL', '')!r} "
        f"({type(exc).__name__}: {exc}); set MUJOCO_GL to one of {', '.join(GL_BACKENDS)} that "
        "this machine has (egl renders offscreen)"
    ) from None
