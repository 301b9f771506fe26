"""The model lab: compare the kinematic model with measurements, see where it fails, learn which
physical effect is missing, add it, watch the error fall.

    from arm import read_measurements
    import lab

    data = read_measurements("data.csv")
    s = lab.screen(data, "seed", "geometric", noise_mm=0.015)   # which rows count, once
    d = lab.diagnose(s)
    print(d.verdict, d.suggestion)            # e.g. compliance  geometric,compliance[2,3]
    result = lab.fit(s, effects=d.suggestion, validate=read_measurements("other.csv"))
    print(result.table())

Every entry point (``screen``, ``fit``, ``diagnose``, ``discover``, ``lab.report.build_report``)
takes ``data, robot, effects`` and then the options: ``options=`` one :class:`LabOptions`, or its
fields as keywords (``lab.options.OptionFields``), resolved once per call. Every result has ``to_dict()`` (the JSON of docs/format.md, the lab's JSON
output) and ``summary()``. Cautions are :class:`LabWarning` s besides the log. Pure numerics: no
simulator, no plotting here (see ``lab.report``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lab.bagging import Bag, bag
    from lab.diagnosis import Candidate, Diagnosis, Hint, diagnose
    from lab.discovery import Discovery, discover
    from lab.errors import (
        ContaminatedError,
        FitError,
        ImplausibleAcceptedWarning,
        LabError,
        LabWarning,
        NoiseRefutedError,
        OrientationNotFittedWarning,
        PoorPoseSetWarning,
        RegistrationError,
        RowsLeftOutWarning,
        ValidationMismatchError,
        ValidationMismatchWarning,
    )
    from lab.estimation import identifiability_of
    from lab.export import compensate, export_robot
    from lab.identifiability import Identifiability, analyse
    from lab.identification import fit
    from lab.options import LabOptions
    from lab.planning import Plan, plan
    from lab.registration import StationRegistration, register_station
    from lab.result import FitResult
    from lab.screening import Screen, screen
    from lab.urdf_export import export_urdf, read_calibrated_urdf

# each public name and the module that defines it: importing ``lab`` (or ``lab.text``) loads
# nothing else until a name is used, so the command line's ``--help`` stays fast
_HOME = {
    "Bag": "lab.bagging",
    "bag": "lab.bagging",
    "Candidate": "lab.diagnosis",
    "Diagnosis": "lab.diagnosis",
    "Hint": "lab.diagnosis",
    "diagnose": "lab.diagnosis",
    "Discovery": "lab.discovery",
    "discover": "lab.discovery",
    "ContaminatedError": "lab.errors",
    "FitError": "lab.errors",
    "ImplausibleAcceptedWarning": "lab.errors",
    "LabError": "lab.errors",
    "LabWarning": "lab.errors",
    "NoiseRefutedError": "lab.errors",
    "ValidationMismatchError": "lab.errors",
    "ValidationMismatchWarning": "lab.errors",
    "OrientationNotFittedWarning": "lab.errors",
    "PoorPoseSetWarning": "lab.errors",
    "RowsLeftOutWarning": "lab.errors",
    "RegistrationError": "lab.errors",
    "compensate": "lab.export",
    "export_robot": "lab.export",
    "StationRegistration": "lab.registration",
    "register_station": "lab.registration",
    "export_urdf": "lab.urdf_export",
    "read_calibrated_urdf": "lab.urdf_export",
    "identifiability_of": "lab.estimation",
    "Identifiability": "lab.identifiability",
    "analyse": "lab.identifiability",
    "fit": "lab.identification",
    "LabOptions": "lab.options",
    "Plan": "lab.planning",
    "plan": "lab.planning",
    "FitResult": "lab.result",
    "Screen": "lab.screening",
    "screen": "lab.screening",
}


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'lab' has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value


__all__ = [
    "Bag",
    "Candidate",
    "ContaminatedError",
    "Diagnosis",
    "Discovery",
    "FitError",
    "FitResult",
    "Hint",
    "Identifiability",
    "ImplausibleAcceptedWarning",
    "LabError",
    "LabOptions",
    "LabWarning",
    "NoiseRefutedError",
    "OrientationNotFittedWarning",
    "Plan",
    "PoorPoseSetWarning",
    "RegistrationError",
    "RowsLeftOutWarning",
    "Screen",
    "StationRegistration",
    "ValidationMismatchError",
    "ValidationMismatchWarning",
    "analyse",
    "bag",
    "compensate",
    "diagnose",
    "discover",
    "export_robot",
    "export_urdf",
    "fit",
    "identifiability_of",
    "plan",
    "read_calibrated_urdf",
    "register_station",
    "screen",
]
