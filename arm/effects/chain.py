"""The catalogue's chain effects (:class:`arm.effects.base.ChainEffect`): the geometric errors
of the DH table, base and tool, and thermal growth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from arm.description import RobotDescription
from arm.effect_api import ArmSize, ChainState
from arm.effects.base import ChainEffect
from arm.params import BASE_NAMES, TOOL_ROTATION_NAMES, parse_parameter_name
from arm.so3 import rotation_matrix

__all__ = ["REFERENCE_TEMPERATURE", "Geometric", "Thermal", "session_offsets"]

REFERENCE_TEMPERATURE = 20.0  # degC, where thermal growth is zero

_Index = np.ndarray | slice  # positions as an index array, or a slice where consecutive


def session_offsets(values: np.ndarray) -> np.ndarray:
    """Every station's zero offsets (S, 6) from the values of the first S - 1 stations' (S - 1,
    6): the last station's are minus their sum (:class:`Geometric`)."""
    v = np.asarray(values, dtype=float).reshape(-1, 6)
    return np.vstack([v, -v.sum(axis=0, keepdims=True)])


@dataclass(frozen=True)
class _Slots:
    """Where the geometric parameters sit: per DH family (``alpha``, ``a``, ``theta``, ``d``,
    ``beta``) the positions in the effect's vector and the chain rows they correct; the base's six
    positions; the tool offsets' positions, one row of three per target."""

    rows: dict[str, tuple[_Index, _Index]]
    base: np.ndarray  # (6,), or (S, 6) with several stations
    tool: np.ndarray
    tool_rotation: np.ndarray | None = None  # trx, try, trz with an orientation measured
    # each station's zero offsets but the last's (S - 1, 6), positions in the vector; the last
    # station's are minus their sum. None with one station
    rehome: np.ndarray | None = None


class Geometric(ChainEffect):
    """DH errors of every row, Hayati's beta on parallel consecutive axes (replacing that row's d),
    the base transform (measurement frame <- robot base) and the tool offset of each target.

    ``dalpha{i}, da{i}, dtheta{i}, dd{i}`` are the errors of row i (alpha_{i-1}, a_{i-1}, theta_i,
    d_i); ``beta{i-1}`` replaces ``dd{i}`` where z_{i-1} and z_i are parallel; ``bx by bz`` (m) and
    ``brx bry brz`` (rotation vector, rad) are the base transform itself, starting from the
    description's (``bx1``... with several tracker stations, one base each); ``tx ty tz``
    (``tx1``... with several targets) are offsets added to the tool point; ``trx try trz``, where
    an orientation is measured, the tool frame's rotation in the last frame (rotation vector,
    rad).

    With several stations that are sessions of their own (``rehomed``: each was re-homed, the
    files joined by :func:`arm.sessions.join_sessions`), each has its own zero offsets:
    ``dtheta{i}_s{s}`` is joint i's offset in station s's session beyond ``dtheta{i}``, which
    is then the sessions' mean. The last station has no name of its own: its offsets are minus
    the sum of the others' (the offsets of all stations sum to zero), so that ``dtheta{i}`` is
    what an unseen, re-homed session is expected to have (:func:`session_offsets`).
    """

    name = "geometric"
    order = 0
    typical = {
        "dalpha": (6e-4, 1.5e-3),
        "dtheta": (6e-4, 1.5e-3),
        "beta": (6e-4, 1.5e-3),
        "da": (1e-4, 3e-4),
        "dd": (1e-4, 3e-4),
        "b": (2e-4, 1e-3),  # base: small for the seed arm (m, rad)
        "t": (1e-4, 3e-4),  # tool offsets
        "tr": (2e-4, 1e-3),  # the tool frame's rotation: small for a probe aligned to the flange
    }
    description = "DH errors (Hayati beta on parallel axes), base transform and tool offsets"
    # 10 mm for a length error, 50 mrad (2.9 deg) for an angle error: a machined arm is never
    # that far from its drawing. The base and the tool are exempt: a tracker stands metres from
    # the base, anyhow rotated, and a reflector may sit hundreds of millimetres off the flange.
    # Those of an arm up to a UR10's size: a larger arm's lengths are bounded in proportion to
    # its reach (arm.effect_api.ArmSize), its angles keep 50 mrad.
    bounds = {"da": 0.01, "dd": 0.01, "dalpha": 0.05, "dtheta": 0.05, "beta": 0.05}
    lengths = ("da", "dd")

    def plausible_bound(self, name: str, arm: ArmSize | None = None) -> float | None:
        parsed = parse_parameter_name(name)
        if parsed is None or parsed.kind in ("base", "tool", "tool_rotation"):
            return None
        bound = self.bounds.get(parsed.family)
        if bound is None or arm is None or parsed.family not in self.lengths:
            return bound
        return bound * arm.length_factor

    def parameter_names(
        self,
        robot: RobotDescription,
        targets: Sequence[int],
        stations: Sequence[int] = (0,),
        orientation: bool = False,
        rehomed: bool = False,
    ) -> list[str]:
        parallel = robot.parallel_rows()
        names = [f"dalpha{i}" for i in range(1, 7)]
        names += [f"da{i}" for i in range(1, 7)]
        names += [f"dtheta{i}" for i in range(1, 7)]
        names += [f"dd{i}" for i in range(1, 7) if i not in parallel]
        names += [f"beta{i - 1}" for i in parallel]
        if len(stations) == 1:
            names += list(BASE_NAMES)
        else:
            names += [f"{c}{s}" for s in stations for c in BASE_NAMES]
            if rehomed:
                names += [f"dtheta{i}_s{s}" for s in stations[:-1] for i in range(1, 7)]
        if len(targets) == 1:
            names += ["tx", "ty", "tz"]
        else:
            names += [f"{c}{k}" for k in targets for c in ("tx", "ty", "tz")]
        if orientation:
            names += list(TOOL_ROTATION_NAMES)
        return names

    def nominal(self, robot: RobotDescription, names: Sequence[str]) -> np.ndarray:
        base = dict(zip(("bx", "by", "bz"), robot.base_translation, strict=True))
        base |= dict(zip(("brx", "bry", "brz"), robot.base_rotation, strict=True))
        # a calibrated 6-DoF tool frame is kept among the description's effect values
        base |= {
            n: v for n, v in robot.effects.get(self.name, {}).items() if n in TOOL_ROTATION_NAMES
        }

        def start(n: str) -> float:
            parsed = parse_parameter_name(n)
            if parsed is not None and parsed.kind == "base":
                return base[parsed.family]
            return base.get(n, 0.0)

        return np.array([start(n) for n in names], dtype=float)

    def _slots(self, state: ChainState) -> _Slots:
        """Where each row's parameters sit in this effect's vector, once per (robot, targets,
        stations, orientation)."""
        key = (
            state.robot.parallel_rows(),
            state.targets,
            state.stations,
            state.orientation,
            state.rehomed,
        )
        cache = self.__dict__.setdefault("_slot_cache", {})
        if key not in cache:
            names = self.parameter_names(
                state.robot, state.targets, state.stations, state.orientation, state.rehomed
            )
            cache[key] = self._compute_slots(names)
        return cache[key]

    @staticmethod
    def _compute_slots(names: Sequence[str]) -> _Slots:
        idx = {n: k for k, n in enumerate(names)}

        def rows(prefix: str, offset: int = 0) -> tuple[_Index, _Index]:
            """(positions in the vector, DH rows 0..5) of the parameters present; a slice when
            the positions are consecutive, so the columns are written without a gather."""
            pairs = [
                (idx[f"{prefix}{i + offset}"], i - 1)
                for i in range(1, 7)
                if f"{prefix}{i + offset}" in idx
            ]
            at = np.array([d for d, _ in pairs], dtype=int)
            of = np.array([r for _, r in pairs], dtype=int)
            dst: _Index = at
            src: _Index = of
            if len(at) and np.all(np.diff(at) == 1):
                dst = slice(int(at[0]), int(at[-1]) + 1)
            if len(of) and np.all(np.diff(of) == 1):
                src = slice(int(of[0]), int(of[-1]) + 1)
            return dst, src

        tool = [idx[n] for n in names if (p := parse_parameter_name(n)) and p.kind == "tool"]
        base = [idx[n] for n in names if (p := parse_parameter_name(n)) and p.kind == "base"]
        turn = [idx[n] for n in TOOL_ROTATION_NAMES if n in idx]
        rehome = [idx[n] for n in names if (p := parse_parameter_name(n)) and p.kind == "rehome"]
        return _Slots(
            rows={
                "alpha": rows("dalpha"),
                "a": rows("da"),
                "theta": rows("dtheta"),
                "d": rows("dd"),
                "beta": rows("beta", -1),
            },
            base=np.array(base, dtype=int).reshape(-1, 6) if len(base) > 6 else np.array(base),
            tool=np.array(tool, dtype=int).reshape(-1, 3),
            tool_rotation=np.array(turn, dtype=int) if turn else None,
            rehome=np.array(rehome, dtype=int).reshape(-1, 6) if rehome else None,
        )

    def apply(self, inputs, values, state):
        s = self._slots(state)

        def add(base, key):
            dst, src = s.rows[key]
            out = np.array(base, dtype=float, copy=True)
            out[..., src] += values[dst]
            return out

        theta = add(state.chain.theta_offset, "theta")
        if s.rehome is not None and inputs is not None:  # each pose's session's own offsets
            theta = theta + session_offsets(values[s.rehome])[inputs.stations]
        chain = state.chain.replace(
            alpha=add(state.chain.alpha, "alpha"),
            a=add(state.chain.a, "a"),
            theta_offset=theta,
            d=add(state.chain.d, "d"),
            beta=add(state.chain.beta, "beta"),
        )
        b = values[s.base]
        tools = state.tools + values[s.tool]
        extra = {}
        if b.ndim == 2:  # one base per station; the first is also the base
            R = rotation_matrix(b[:, 3:])
            extra = {"station_t": b[:, :3], "station_r": b[:, 3:], "station_R": R}
            b = b[0]
        if s.tool_rotation is not None:
            tr = values[s.tool_rotation]
            extra |= {"tool_r": tr, "tool_R": rotation_matrix(tr)}
        return state.replace(
            chain=chain,
            base_t=b[:3],
            base_r=b[3:],
            base_R=rotation_matrix(b[3:]),
            tools=tools,
            **extra,
        )

    def jacobian(self, inputs, values, sens):
        return self._jacobian_from_into(inputs, values, sens)

    def jacobian_into(self, inputs, values, sens, out):
        s = self._slots(sens.state)
        for key, rows in (
            ("alpha", "rows_alpha"),
            ("a", "rows_a"),
            ("theta", "rows_theta"),
            ("d", "rows_d"),
        ):
            dst, src = s.rows[key]
            if isinstance(dst, slice) or len(dst):
                out[dst] = getattr(sens, rows)[src]
        dst, src = s.rows["beta"]  # only the few parallel rows have one
        if isinstance(dst, slice) or len(dst):
            out[dst] = sens.beta_rows(src)
        # lengths a and d scale with thermal growth: d p / d(da) = s * d p / d(a)
        if sens.state.length_scale is not None:
            for key in ("a", "d"):
                out[s.rows[key][0]] *= sens.state.length_scale
        if s.base.ndim == 2:
            for k, cols in enumerate(s.base):
                out[cols] = sens.base_cols * (inputs.stations == k)
        else:
            out[s.base] = sens.base_cols
        if s.rehome is not None:
            last = (inputs.stations == len(s.rehome)).astype(float)
            for k, cols in enumerate(s.rehome):
                out[cols] = sens.rows_theta * ((inputs.stations == k) - last)
        if s.tool_rotation is not None:
            out[s.tool_rotation] = sens.tool_rotation_cols
        tool = sens.tool_cols
        if len(s.tool) == 1:
            out[s.tool[0]] = tool
        else:
            for k, cols in enumerate(s.tool):
                out[cols] = tool * (inputs.target == k)
        return True


class Thermal(ChainEffect):
    """Lengths a and d (nominal plus error) scaled by ``1 + kappa (T - 20 degC)``; base and tool not."""

    name = "thermal"
    order = 10
    typical = {"kappa": (1.2e-5, 2.3e-5)}
    positive = True
    columns = ("temperature",)
    description = "thermal growth: a, d scaled by 1 + kappa (T - 20 degC)"

    def parameter_names(self, robot, targets):
        return ["kappa"]

    def _dT(self, inputs):
        return inputs.column("temperature") - REFERENCE_TEMPERATURE

    def apply(self, inputs, values, state):
        scale = 1.0 + values[0] * self._dT(inputs)
        chain = state.chain.replace(
            a=np.asarray(state.chain.a)[None, :] * scale[:, None],
            d=np.asarray(state.chain.d)[None, :] * scale[:, None],
        )
        prev = state.length_scale if state.length_scale is not None else 1.0
        return state.replace(chain=chain, length_scale=prev * scale)

    def jacobian(self, inputs, values, sens):
        return self._jacobian_from_into(inputs, values, sens)

    def jacobian_into(self, inputs, values, sens, out):
        # d p / d kappa = sum_i (d p / d a_i) a_i' + (d p / d d_i) d_i', a' = a_nominal dT
        dT = self._dT(inputs)
        a = np.asarray(sens.state.chain.a, dtype=float)
        d = np.asarray(sens.state.chain.d, dtype=float)
        a = a[:, None, None] if a.ndim == 1 else a.T[:, None, :]
        d = d[:, None, None] if d.ndim == 1 else d.T[:, None, :]
        col = (sens.rows_a * a).sum(axis=0) + (sens.rows_d * d).sum(axis=0)
        out[0] = col * (dT / (1.0 + values[0] * dT))
        return True
