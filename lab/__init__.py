"""The model lab: compare the kinematic model with measurements, see where it fails, learn which
physical effect is missing, add it, watch the error fall.

    from arm import read_measurements, load_robot
    from lab import fit, diagnose, plan

    data = read_measurements("data.csv")
    d = diagnose(data, "seed", "geometric", noise_mm=0.015)
    print(d.verdict, d.suggestion)            # e.g. compliance  geometric,compliance[2,3]
    result = fit(data, "seed", d.suggestion, validate=read_measurements("other.csv"))
    print(result.table())

Every result has ``to_dict()`` (the JSON of docs/format.md, the lab's JSON output) and
``summary()``. Pure numerics: no simulator, no plotting here (see ``lab.report``).
"""

from lab.diagnosis import Candidate, Diagnosis, Hint, diagnose
from lab.discovery import Discovery, discover
from lab.identifiability import Identifiability, analyse
from lab.identification import FitError, FitResult, fit, identifiability_of
from lab.planning import Plan, plan

__all__ = [
    "Candidate",
    "Diagnosis",
    "Discovery",
    "FitError",
    "FitResult",
    "Hint",
    "Identifiability",
    "Plan",
    "analyse",
    "diagnose",
    "discover",
    "fit",
    "identifiability_of",
    "plan",
]
