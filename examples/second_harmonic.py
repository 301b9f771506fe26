"""A user effect the catalogue lacks: the second harmonic of a transmission error.

A strain-wave (harmonic) gear's flexspline is elliptical, so its transmission error repeats twice
per output revolution: ``theta_i = q_i + h2s_i * sin(2 q_i) + h2c_i * cos(2 q_i)``. The catalogue's
``transmission`` effect has only the first harmonic. Load this file and fit with it:

    sixaxis lab fit data.csv --effect-module examples/second_harmonic.py \\
        --effects geometric,second_harmonic[3]

or from Python:

    from envs.effects import load_effect_module
    from lab import fit
    load_effect_module("examples/second_harmonic.py")
    result = fit(data, robot, "geometric,second_harmonic[3]")

A joint-angle effect is linear in its parameters: it names its terms (parameters are
``{term}{joint}``: ``h2s3``, ``h2c3``) and gives the regressor of each on the joint angle; the
error model derives the identification Jacobian from it. ``typical`` sets the size of an error
that is worth fitting (the lab fixes parameters whose typical-size error moves the points by less
than the instrument's noise) and the range :func:`envs.sampling.sample_parameters` draws from.
"""

import numpy as np

from envs.effects import JointAngleEffect


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
