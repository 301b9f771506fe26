"""A user effect the catalogue lacks: the second harmonic of a transmission error.

A strain-wave (harmonic) gear's flexspline is elliptical, so its transmission error repeats twice
per output revolution: ``theta_i = q_i + h2s_i * sin(2 q_i) + h2c_i * cos(2 q_i)``. The catalogue's
``transmission`` effect has only the first harmonic. Load this file and fit with it:

    sixaxis lab fit data.csv --effect-module examples/second_harmonic.py \\
        --effects geometric,second_harmonic[3]

or from Python:

    from arm.effects import load_effect_module
    from lab import fit
    load_effect_module("examples/second_harmonic.py")
    result = fit(data, robot, "geometric,second_harmonic[3]")

A joint-angle effect is linear in its parameters: it names its terms (parameters are
``{term}{joint}``: ``h2s3``, ``h2c3``) and gives the regressor of each on the joint angle; the
error model derives the identification Jacobian from it. ``typical`` sets the size of an error
that is worth fitting (the lab fixes parameters whose typical-size error moves the points by less
than the instrument's noise) and the range :func:`arm.sampling.sample_parameters` draws from.
"""

import numpy as np

from arm.effects import JointAngleEffect


class SecondHarmonic(JointAngleEffect):
    name = "second_harmonic"
    terms = ("h2s", "h2c")
    typical = {"h2s": (1e-4, 5e-4), "h2c": (1e-4, 5e-4)}
    description = (
        "second-harmonic transmission error: theta_i += h2s_i sin(2 q_i) + h2c_i cos(2 q_i)"
    )

    def basis(self, inputs, joint, term):
        qj = inputs.q[:, joint - 1]
        return np.sin(2 * qj) if term == "h2s" else np.cos(2 * qj)


def simulate(out_dir: str = ".", joint: int = 3, n: int = 200, seed: int = 0) -> None:
    """Write ``calibration.csv`` and ``validation.csv`` (docs/format.md, the measurement CSV)
    measured on a simulated seed arm with random geometric errors and a hidden second harmonic on
    ``joint`` (2e-4 rad), 15 um tracker noise: data to try the loop on.

        python examples/second_harmonic.py /tmp/h2
        sixaxis lab diagnose /tmp/h2/calibration.csv --noise-mm 0.015
        sixaxis lab fit /tmp/h2/calibration.csv --validate /tmp/h2/validation.csv \\
            --effect-module examples/second_harmonic.py --effects geometric,second_harmonic[3]
    """
    from pathlib import Path

    from arm.description import seed_robot
    from arm.effects import register_effect
    from arm.errormodel import ErrorModel
    from arm.measurements import MeasurementSet, write_measurements
    from arm.sampling import sample_parameters, sample_poses

    register_effect(SecondHarmonic)
    robot, rng = seed_robot(), np.random.default_rng(seed)
    truth = ErrorModel(robot, f"geometric,second_harmonic[{joint}]")
    p = sample_parameters(truth, rng, only=truth.layout.names[truth.layout.slice("geometric")])
    p[truth.layout.indices([f"h2s{joint}", f"h2c{joint}"])] = [2e-4, -1e-4]
    for name, m in (("calibration.csv", n), ("validation.csv", n // 2)):
        q = sample_poses(robot, m, rng)
        xyz = truth.predict(truth.inputs(q, {}), p) + rng.normal(0.0, 15e-6, (m, 3))
        path = Path(out_dir) / name
        write_measurements(MeasurementSet(q, xyz, {}, "simulated"), path)
        print(f"wrote {path} ({m} poses)")


if __name__ == "__main__":
    import sys

    simulate(*sys.argv[1:2])
