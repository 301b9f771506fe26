"""A simulated campaign beyond one 3-D point, drawn from the error model itself (fast, exact):
an arm with geometric errors of the paper's size, measured from tracker stations metres away, a
6-DoF probe turned on the flange, noise growing with the distance from the tracker (as the UR5
set's GTS3800 states: 15 um + 6 um/m) and each row's stated uncertainties."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from arm.description import RobotDescription
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from arm.noise import InstrumentNoise
from arm.sampling import sample_poses
from arm.so3 import rotation_matrix, rotation_vector

# stations: near and far from the arm, each turned about the vertical and slightly tilted
STATIONS = {
    1: (2.0, -1.2, -0.6, 0.002, -0.001, 2.2),
    2: (-9.0, 7.5, -0.9, 0.001, 0.003, -0.8),
    3: (4.5, 5.0, -0.3, -0.002, 0.001, 0.9),
}
TOOL_ROTATION = (0.7, -1.0, 0.4)
NOISE = InstrumentNoise(mm=0.015, ppm=6.0, mrad=0.05)


@dataclass
class PoseCampaign:
    robot: RobotDescription
    truth: ErrorModel
    params: np.ndarray
    rng: np.random.Generator
    noise: InstrumentNoise = NOISE

    def measure(
        self, n: int, stations=(1, 2), orientation_fraction: float = 1.0, stds: bool = True
    ) -> tuple[MeasurementSet, np.ndarray]:
        """``n`` random poses measured from ``stations`` in consecutive blocks; returns the set and
        the noise-free points (N, 3)."""
        rng = self.rng
        q = sample_poses(self.robot, n, rng)
        which = np.array([stations[i * len(stations) // n] for i in range(n)], dtype=float)
        x, R = self.truth.predict_pose(self.truth.inputs(q, {"station": which}), self.params)
        sigma = self.noise.point_sigma(np.linalg.norm(x, axis=1))
        xyz = x + sigma[:, None] * rng.normal(size=(n, 3))
        sr = self.noise.mrad * 1e-3 if self.noise.mrad else 0.0
        measured = rotation_vector(rotation_matrix(rng.normal(0.0, sr, (n, 3))) @ R)
        seen = rng.random(n) < orientation_fraction
        mask = np.ones((n, 6), dtype=bool)
        mask[:, 3:] = seen[:, None]
        std = None
        if stds:
            std = np.column_stack([np.repeat(sigma[:, None], 3, axis=1), np.full((n, 3), sr)])
            std[~seen, 3:] = np.nan
        data = MeasurementSet(
            q,
            xyz,
            {"station": which},
            "simulated 6-DoF campaign",
            orientation=measured,
            mask=mask,
            std=std,
        )
        return data, x


def pose_campaign(
    robot: RobotDescription, seed: int = 0, effects: str = "geometric"
) -> PoseCampaign:
    """The truth: geometric errors of the paper's size (0.1-0.3 mm, 0.6-1.5 mrad), three
    stations' bases, the probe's rotation on the flange; with ``effects`` naming compliance,
    c2 = c3 = 8e-6 rad/(N m) (the top of the typical range) besides."""
    rng = np.random.default_rng(seed)
    truth = ErrorModel(robot, effects, stations=tuple(STATIONS), orientation=True)
    p = truth.nominal()
    lay = truth.layout
    for k, name in enumerate(lay.names):
        sign = rng.choice([-1.0, 1.0])
        if name.startswith(("dalpha", "dtheta", "beta")):
            p[k] = sign * rng.uniform(6e-4, 1.5e-3)
        elif name.startswith(("da", "dd")):
            p[k] = sign * rng.uniform(1e-4, 3e-4)
        elif name in ("tx", "ty", "tz"):
            p[k] += sign * rng.uniform(1e-4, 3e-4)
        elif name in ("c2", "c3"):
            p[k] = 8e-6
    for sid, base in STATIONS.items():
        p[lay.indices([f"{c}{sid}" for c in ("bx", "by", "bz", "brx", "bry", "brz")])] = base
    p[lay.indices(["trx", "try", "trz"])] = TOOL_ROTATION
    return PoseCampaign(robot, truth, p, rng)
