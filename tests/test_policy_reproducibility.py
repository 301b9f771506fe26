"""A shipped policy's recorded rows reproduce on another CPU: the promise of ``sixaxis
reproduce --rtol 1e-6`` (README), kept without a second machine, two ways.

1. **Another CPU's kernels, here.** MKL, torch and numpy choose their vector kernels at run time;
   environment variables make them take another CPU's (MKL's conditional-numerical-reproducibility
   code path, torch's AVX2 kernels, numpy without AVX-512). A subprocess so configured replays
   recorded episodes of every shipped policy, which must match the .json record within the
   promised rtol. (In float32 this moved the old plain ``ppo``'s settled RMS from 3.229 to 3.303
   mm; in float64 the policies move by about 1e-11.)

2. **How far the closed loop carries a rounding difference.** Every recorded episode is run
   again with each observation multiplied by ``1 + 1e-12 * (+-1)``. A loop that is not chaotic
   carries this on at the plant's own floor: its dry friction sticks or slips, so even
   ``feedforward`` (no learning) moves by up to about 3e-5, and an isolated flip of a discrete
   feature (a joint's direction of motion) moves one episode's metric by up to a few 1e-3. Between
   CPUs, where float64 results differ by a unit in the last place, not by 1e-12, such a flip is
   some 1e4 times rarer. A chaotic loop moves most episodes: the median over a policy's episodes
   must stay at the floor (``MEDIAN_RTOL``) and no episode beyond ``MAX_RTOL``. The old plain
   ``ppo`` (bang-bang against the rate limit) moves by up to 0.55, its median by 1e-2, and fails
   by name (``tests/data/chaotic-ppo``: the policy shipped before the plain PPO was retrained on
   the operational-space interface, which passes).

   The issue that asked for this test named rtol 1e-6 at a 1e-12 perturbation; nothing passes that
   on this plant, the non-learned controllers included, so the test separates a chaotic loop from
   a stable one, and test 1 keeps the cross-CPU promise itself.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from agents.policy import POLICY_DIR, load_policy_file
from agents.registry import POLICIES
from agents.training import evaluate_network, evaluate_policy

#: the relative tolerance `sixaxis reproduce` promises on another machine (README)
REPRODUCE_RTOL = 1e-6
PERTURBATION = 1e-12
#: a stable loop under that perturbation: the median episode at the plant's floor, none beyond
#: an isolated flip of a discrete feature
MEDIAN_RTOL = 1e-4
MAX_RTOL = 1e-2
#: no exception: the old bang-bang plain `ppo` (up to 0.55 relative) was retrained on the
#: operational-space interface; it is kept in tests/data as the check's counterexample
KNOWN_CHAOTIC: dict[str, tuple[float, float]] = {}
METRICS = ("rms_settled_mm", "rms_mm", "return")
ROOT = Path(__file__).resolve().parents[1]

#: another CPU's kernels: MKL's reproducible code path, torch's AVX2 kernels, numpy without
#: AVX-512 (OpenBLAS is pinned by OPENBLAS_CORETYPE where the machine sets it)
OTHER_CPU = {
    "MKL_CBWR": "COMPATIBLE",
    "ATEN_CPU_CAPABILITY": "avx2",
    "NPY_DISABLE_CPU_FEATURES": "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL "
    "AVX512_SPR",
}


def _record(name: str) -> dict:
    return json.loads((POLICY_DIR / f"{name}.json").read_text())["leaderboard"]


def drifts(got: dict, recorded: dict) -> dict[str, float]:
    """Per episode (``scenario/seed index``), the largest relative difference of its metrics."""
    out = {}
    for sc, rows in got.items():
        for key in METRICS:
            a = np.asarray(recorded[sc][key], dtype=float)
            b = np.asarray(rows[key], dtype=float)
            rel = np.abs(b - a) / np.maximum(np.abs(a), 1e-300)
            for k, r in enumerate(rel):
                out[f"{sc}/{k}"] = max(out.get(f"{sc}/{k}", 0.0), float(r))
    return out


def worst_drift(got: dict, recorded: dict) -> tuple[float, str]:
    """The largest relative difference of any metric of any episode, and where it is."""
    d = drifts(got, recorded)
    where = max(d, key=d.__getitem__)
    return d[where], where


def chaos(d: dict[str, float]) -> tuple[float, float]:
    """(median, max) over episodes of the per-episode drift."""
    v = np.array(list(d.values()))
    return float(np.median(v)), float(v.max())


def test_every_shipped_policy_records_float64_inference():
    for name in POLICIES:
        assert _record(name).get("inference") == "float64", name


@pytest.mark.parametrize("name", POLICIES)
def test_recorded_rows_reproduce_with_another_cpus_kernels(name):
    """Backlash and all, where the residuals' differences were largest in float32."""
    row = _record(name)
    code = textwrap.dedent(
        f"""
        import json
        from agents.training import evaluate_policy
        from agents.policy import POLICY_DIR
        row = json.loads((POLICY_DIR / "{name}.json").read_text())["leaderboard"]
        got = evaluate_policy(POLICY_DIR / "{name}.npz", scenarios=("backlash", "all"),
                              seeds=tuple(row["seeds"]), env_kwargs=row["env"],
                              episode_seconds=row["episode_seconds"],
                              settle_seconds=row["settle_seconds"])
        print(json.dumps(got))
        """
    )
    env = os.environ | OTHER_CPU
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, check=True
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    drift, where = worst_drift(got, row["episodes"])
    assert drift <= REPRODUCE_RTOL, f"{name}: {where} differs by {drift:.2e} on other kernels"


def _perturbed(path: Path, row: dict, scenarios: tuple[str, ...], seeds: tuple[int, ...]) -> dict:
    return evaluate_policy(
        path,
        scenarios=scenarios,
        seeds=seeds,
        env_kwargs=row["env"],
        episode_seconds=row["episode_seconds"],
        settle_seconds=row["settle_seconds"],
        perturb_rel=PERTURBATION,
    )


@pytest.mark.slow
@pytest.mark.parametrize("name", POLICIES)
def test_a_rounding_difference_stays_a_rounding_difference(name):
    """Every recorded episode of every shipped policy, its observations perturbed."""
    row = _record(name)
    got = _perturbed(POLICY_DIR / f"{name}.npz", row, tuple(row["episodes"]), tuple(row["seeds"]))
    d = drifts(got, row["episodes"])
    median, worst = chaos(d)
    where = max(d, key=d.__getitem__)
    med_ok, max_ok = KNOWN_CHAOTIC.get(name, (MEDIAN_RTOL, MAX_RTOL))
    assert median <= med_ok and worst <= max_ok, (
        f"{name} is chaotic: a relative perturbation of {PERTURBATION:g} moves its episodes by "
        f"{median:.2e} (median; at most {med_ok:g}) and {where} by {worst:.2e} (at most "
        f"{max_ok:g}); another CPU would not reproduce its rows"
    )


def test_the_check_names_a_chaotic_policy():
    """The plain PPO shipped before this test (bang-bang against the rate limit) fails the check
    the shipped policies pass, on three of its own recorded episodes."""
    path = Path(__file__).parent / "data" / "chaotic-ppo.npz"
    row = json.loads(path.with_suffix(".json").read_text())["leaderboard"]
    seeds = tuple(row["seeds"][:3])
    network, meta = load_policy_file(path)
    kwargs = dict(
        scenarios=("backlash",),
        seeds=seeds,
        env_kwargs=row["env"],
        episode_seconds=row["episode_seconds"],
        settle_seconds=row["settle_seconds"],
    )
    plain = evaluate_network(network, meta, **kwargs)
    median, worst = chaos(
        drifts(evaluate_network(network, meta, perturb_rel=PERTURBATION, **kwargs), plain)
    )
    assert median > MEDIAN_RTOL or worst > MAX_RTOL, (median, worst)
