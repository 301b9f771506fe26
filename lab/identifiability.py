"""Which parameters a set of measurements can identify, and how well.

The identification Jacobian ``J`` (d measured points / d parameters, (N, 3, P)) is column-scaled
so that every column has an RMS of 1 m per pose (``scale_j = sqrt(N) / ||J_j||``): a parameter's
unit no longer matters, only how its effect on the measured points differs from the others'.

* **Zero columns**: a parameter whose typical-size error (its effect's ``typical`` range, upper
  end) moves the points by less than :data:`ZERO_COLUMN_M` RMS per pose moves nothing (``dtheta6``
  with the target on joint 6's axis; ``c1`` where gravity has no torque about joint 1).
* **Rank**: the scaled columns are taken in a priority order (base, tool, then the DH table row by
  row, then the other effects), and a column is kept when its part orthogonal to the columns kept
  before it exceeds :data:`RANK_TOL` of its norm. Structural dependencies (the base absorbs the
  first row; the tool absorbs ``dd6``) are exact, with relative residuals at round-off (1e-16),
  while identifiable parameters of real pose sets stay above 1e-4; 1e-8 (the square root of the
  machine epsilon, the accuracy of a first-order Jacobian) lies safely inside that gap. The kept
  columns are the identifiable (base) parameters; each other one is fixed at its nominal value and
  named with the null-space combination it belongs to: ``dd1 - bz`` means that raising ``dd1`` by
  1 m and lowering ``bz`` by 1 m moves no measured point.
* **Quality** of the identifiable set: its singular values, the condition number (a warning over
  :data:`CONDITION_WARNING`) and the observability indices O1 = (s_1 ... s_L)^(1/L) / sqrt(N)
  (Borm & Menq 1991) and O4 = s_min^2 / s_max (Nahvi & Hollerbach 1996).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from arm import errors
from arm.effect_api import ModelInputs
from arm.errormodel import ErrorModel
from arm.params import BASE_NAMES, ROW_FAMILIES, parse_parameter_name
from lab.errors import PoorPoseSetWarning

__all__ = ["CONDITION_WARNING", "Identifiability", "analyse", "analyse_jacobian", "analyse_model"]

log = logging.getLogger(__name__)

RANK_TOL = 1e-8
ZERO_COLUMN_M = 1e-12  # m RMS per pose: far below any instrument, far above FK round-off (1e-16 m)
CONDITION_WARNING = 100.0
HELD_SHOWN = 12  # the parameters held at given values that a summary names (a bag holds hundreds)
_COEF_TOL = 1e-6  # scaled null-space coefficients below this are round-off, not dependencies
_LABEL_TOL = 1e-2  # and below this too small to name in a label


@dataclass(frozen=True)
class Identifiability:
    """The identifiability of a model's parameters from one set of poses.

    ``identifiable`` marks the parameters that are fitted; every other one is fixed at nominal and
    listed in ``combinations`` with the null-space direction it spans (coefficients in SI units,
    its own coefficient 1; an empty dict for a parameter that moves nothing at all).
    ``singular_values`` are those of the scaled Jacobian restricted to the identifiable columns.
    ``held`` names the parameters the caller holds at known values (``lab.fit``'s ``fixed``):
    neither identified nor unidentifiable, the others are judged without their columns.
    """

    names: tuple[str, ...]
    identifiable: np.ndarray
    scale: np.ndarray
    singular_values: np.ndarray
    combinations: dict[str, dict[str, float]]
    labels: dict[str, str]
    n_poses: int
    weak: tuple[str, ...] = ()
    noise: float | None = None
    held: tuple[str, ...] = ()

    @property
    def rank(self) -> int:
        return int(self.identifiable.sum())

    @property
    def n_parameters(self) -> int:
        return len(self.names)

    @property
    def identifiable_names(self) -> tuple[str, ...]:
        return tuple(n for n, ok in zip(self.names, self.identifiable, strict=True) if ok)

    @property
    def fixed_names(self) -> tuple[str, ...]:
        """The parameters fixed at nominal because the data cannot identify them (not those
        held)."""
        held = set(self.held)
        return tuple(
            n
            for n, ok in zip(self.names, self.identifiable, strict=True)
            if not ok and n not in held
        )

    @property
    def condition_number(self) -> float:
        s = self.singular_values
        return float(s[0] / s[-1]) if s.size and s[-1] > 0 else float("inf")

    @property
    def o1(self) -> float:
        """Borm & Menq: the geometric mean of the singular values over sqrt(number of poses)."""
        s = self.singular_values
        if not s.size or s[-1] <= 0:
            return 0.0
        return float(np.exp(np.mean(np.log(s))) / np.sqrt(self.n_poses))

    @property
    def o4(self) -> float:
        """Nahvi & Hollerbach's noise amplification index: s_min^2 / s_max."""
        s = self.singular_values
        return float(s[-1] ** 2 / s[0]) if s.size and s[0] > 0 else 0.0

    @property
    def unidentifiable(self) -> list[str]:
        """Each fixed parameter by name, or the combination it belongs to (``dd1 - bz``)."""
        return [self.labels[n] for n in self.fixed_names]

    def to_dict(self) -> dict:
        return {
            "rank": self.rank,
            "n_parameters": self.n_parameters,
            "identifiable": list(self.identifiable_names),
            "unidentifiable": self.unidentifiable,
            "condition_number": _finite(self.condition_number),
            "o1": self.o1,
            "o4": self.o4,
        }

    def summary(self) -> str:
        lines = [
            f"{self.rank} of {self.n_parameters} parameters identifiable from {self.n_poses} poses; "
            f"condition number {self.condition_number:.3g}, O1 {self.o1:.3g}, O4 {self.o4:.3g}"
        ]
        if self.fixed_names:
            lines.append("fixed at nominal: " + "; ".join(self.unidentifiable))
        if self.held:
            shown = ", ".join(self.held[:HELD_SHOWN])
            more = len(self.held) - HELD_SHOWN
            lines.append(
                f"held at the values given ({len(self.held)}): {shown}"
                + (f", and {more} more" if more > 0 else "")
            )
        return "\n".join(lines)


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def format_combination(
    name: str, coefs: dict[str, float], weights: dict[str, float] | None = None
) -> str:
    """``dd1 - bz``, ``dalpha6 - 0.2856*dd5``; the bare name for a parameter that moves nothing.

    ``weights`` (the scaled coefficients) drop terms under :data:`_LABEL_TOL` from the label."""
    out = name
    for k, c in coefs.items():
        if k == name or (weights is not None and abs(weights[k]) < _LABEL_TOL):
            continue
        sign = "-" if c < 0 else "+"
        mag = f"{abs(c):.4g}"
        out += f" {sign} {k}" if mag == "1" else f" {sign} {mag}*{k}"
    return out


# --------------------------------------------------------------------------------------------------


def priority_order(names: Sequence[str], geometric: Sequence[str] = ()) -> np.ndarray:
    """The order in which columns are offered to the rank test: the base transform, the tool
    offsets, the DH table row by row (alpha, a, theta, d or Hayati's beta), then everything else in
    its order, a session's own zero offsets (``dtheta{i}_s{s}``) after the shared table.
    Dependent parameters are fixed, so the base absorbs row 1 and the tool absorbs ``dd6`` and
    ``dtheta6``, and each station's base its session's offset of joint 1, as a calibration
    engineer would state it."""
    geo = set(geometric)

    def key(k: int) -> tuple:
        n = names[k]
        p = parse_parameter_name(n) if n in geo else None
        if p is not None:
            if p.kind == "base":  # with several stations: station by station, as laid out
                return (0, BASE_NAMES.index(n) if p.number is None else k, 0)
            if p.kind in ("tool", "tool_rotation"):
                return (1, k, 0)
            if p.kind == "beta":  # beta_{i-1} sits in row i in place of dd_i
                return (2, p.row, 3)
            if p.kind == "row":
                return (2, p.row, ROW_FAMILIES.index(p.family))
            if p.kind == "rehome":  # a session's own zero offsets: after the shared table
                return (2, 7, k)
        return (3, k, 0)

    return np.array(sorted(range(len(names)), key=key), dtype=int)


def typical_magnitudes(model: ErrorModel) -> np.ndarray:
    """The upper end of each parameter's typical error (its effect's ``typical`` table); 1 (SI)
    for parameters without one."""
    out = np.ones(len(model.layout))
    for e in model.effects:
        sl = model.layout.slice(e.name)
        for k, name in zip(range(sl.start, sl.stop), model.layout.names[sl], strict=True):
            rg = e.typical_range(name)
            if rg is not None:
                out[k] = rg[1]
    return out


def analyse(
    J: np.ndarray,
    names: Sequence[str],
    *,
    typical: np.ndarray | None = None,
    scale: np.ndarray | None = None,
    priority: np.ndarray | None = None,
    noise: float | None = None,
    tol: float = RANK_TOL,
    warn: bool = True,
    n_poses: int | None = None,
) -> Identifiability:
    """Identifiability from an identification Jacobian ``J`` (N, 3, P) (or (3N, P)), or from
    the R of its QR decomposition with ``n_poses`` given (only inner products of its columns
    count, and they are the same).

    ``typical`` (P,) are typical error sizes (default 1 in SI units): a parameter is fixed when its
    typical-size error moves the points by less than :data:`ZERO_COLUMN_M` RMS per pose and, given
    the per-axis ``noise`` (m), when what it adds to the parameters before it moves the points by
    less than the noise (norm over all 3N coordinates): the data would determine it no better than
    its typical size, and fitting it would fit noise (listed in ``weak``). ``scale`` (P,) is a
    fixed column scaling (default: columns to an RMS of 1 per pose; give one scaling to compare
    pose sets); ``priority`` the order in which columns are offered (default: as given).
    """
    names = tuple(names)
    P = len(names)
    A = np.asarray(J, dtype=float)
    if n_poses is None:
        n_poses = A.shape[0] if A.ndim == 3 else A.shape[0] // 3
    A = A.reshape(-1, P)
    norms = np.linalg.norm(A, axis=0)
    typ = np.ones(P) if typical is None else np.asarray(typical, dtype=float)
    zero = norms * typ < ZERO_COLUMN_M * np.sqrt(max(n_poses, 1))
    if scale is None:
        scale = np.where(zero, 0.0, np.sqrt(n_poses) / np.where(zero, 1.0, norms))
    else:
        scale = np.where(zero, 0.0, np.asarray(scale, dtype=float))
    As = A * scale
    order = np.arange(P) if priority is None else np.asarray(priority, dtype=int)

    kept: list[int] = []
    weak: list[int] = []
    Qf = np.empty((P, A.shape[0]))  # orthonormal rows spanning the kept columns (Gram-Schmidt)
    for j in order:
        if zero[j]:
            continue
        Q = Qf[: len(kept)]
        a = As[:, j]
        r = a - (Q @ a) @ Q
        r -= (Q @ r) @ Q  # twice is enough (Kahan/Parlett)
        nr = np.linalg.norm(r)
        if nr <= tol * np.linalg.norm(a):
            continue
        if noise is not None and nr * typ[j] / scale[j] < noise:
            weak.append(int(j))
            continue
        Qf[len(kept)] = r / nr
        kept.append(int(j))
    mask = np.zeros(P, dtype=bool)
    mask[kept] = True

    combos: dict[str, dict[str, float]] = {}
    labels: dict[str, str] = {}
    kept_sorted = np.flatnonzero(mask)
    Ak = As[:, kept_sorted]
    # small Gram matrices, not LAPACK on the tall Jacobian: multithreaded QR/SVD of a (3N, P)
    # matrix is several times slower than one gemm (OpenBLAS), and the identifiable columns are
    # well enough conditioned (kept above) for cond(G) = cond(A)^2
    G = Ak.T @ Ak
    dep = np.flatnonzero(~mask & ~zero)
    if dep.size:
        C = np.linalg.solve(G, Ak.T @ As[:, dep]) if kept_sorted.size else np.zeros((0, dep.size))
        for col, j in enumerate(dep):
            c = C[:, col]
            d = {names[j]: 1.0}
            w = {names[j]: 1.0}
            for k, ck in zip(kept_sorted, c, strict=True):
                if abs(ck) > _COEF_TOL:
                    d[names[k]] = float(-ck * scale[k] / scale[j])
                    w[names[k]] = float(-ck)
            combos[names[j]] = d
            # a weak parameter that is mostly independent is too small, not a combination
            rest = np.linalg.norm(As[:, j] - Ak @ c)
            small = j in weak and rest > 0.5 * np.linalg.norm(As[:, j])
            labels[names[j]] = names[j] if small else format_combination(names[j], d, w)
    for j in np.flatnonzero(zero):
        combos[names[j]], labels[names[j]] = {}, names[j]
    ev = np.linalg.eigvalsh(G) if kept_sorted.size else np.empty(0)
    s = np.sqrt(np.clip(ev[::-1], 0.0, None))
    ident = Identifiability(
        names=names,
        identifiable=mask,
        scale=scale,
        singular_values=s,
        combinations=combos,
        labels=labels,
        n_poses=n_poses,
        weak=tuple(names[j] for j in weak),
        noise=noise,
    )
    if warn and ident.condition_number > CONDITION_WARNING:
        text = (
            f"poor pose set: the scaled identification Jacobian has condition number "
            f"{ident.condition_number:.3g} (> {CONDITION_WARNING:g}) over its {ident.rank} "
            "identifiable parameters; plan poses (lab.plan) or fit fewer effects"
        )
        log.warning("%s", text)
        errors.warn(text, PoorPoseSetWarning)
    return ident


def analyse_model(
    model: ErrorModel,
    inputs: ModelInputs,
    params: np.ndarray | None = None,
    *,
    scale: np.ndarray | None = None,
    noise: float | None = None,
    tol: float = RANK_TOL,
    warn: bool = True,
) -> Identifiability:
    """:func:`analyse` of a model's Jacobian at ``params`` (default nominal) on these poses."""
    p = model.nominal() if params is None else np.asarray(params, dtype=float)
    _, J = model.predict(inputs, p, jacobian=True)
    return analyse_jacobian(model, J, scale=scale, noise=noise, tol=tol, warn=warn)


def analyse_jacobian(
    model: ErrorModel,
    J: np.ndarray,
    *,
    scale: np.ndarray | None = None,
    noise: float | None = None,
    tol: float = RANK_TOL,
    warn: bool = True,
    n_poses: int | None = None,
) -> Identifiability:
    """:func:`analyse` with the model's names, typical magnitudes and priority order."""
    names = model.layout.names
    geometric = (
        names[model.layout.slice("geometric")] if "geometric" in model.layout.effects else ()
    )
    return analyse(
        J,
        names,
        typical=typical_magnitudes(model),
        scale=scale,
        priority=priority_order(names, geometric),
        noise=noise,
        tol=tol,
        warn=warn,
        n_poses=n_poses,
    )


def gram_factor(G: np.ndarray, rtol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Rank-revealing pivoted Cholesky (LAPACK ``dpstrf``) of a Gram matrix ``G = A^T A``.

    Returns ``(idx, L)``: the independent columns in pivot order and the lower-triangular factor
    with ``G[idx][:, idx] = L L^T``. A column counts as dependent when its part orthogonal to
    the columns before it is under ``rtol`` of its norm (the test is made on the normalised
    matrix). Tiny matrices, microseconds: the tall matrix is never factored."""
    G = np.asarray(G, dtype=float)
    d = np.sqrt(np.clip(np.diag(G), 0.0, None))
    ok = np.flatnonzero(d > 0)
    if not ok.size:
        return ok, np.zeros((0, 0))
    Gn = G[np.ix_(ok, ok)] / np.outer(d[ok], d[ok])
    c, piv, rank, _ = lapack.dpstrf(Gn, tol=rtol**2, lower=1)
    sel = piv[:rank] - 1
    L = np.tril(c)[:rank, :rank] * d[ok][sel][:, None]
    return ok[sel], L


def orthonormal_basis(A: np.ndarray, rtol: float = 1e-6, overwrite: bool = False) -> np.ndarray:
    """Orthonormal columns spanning the numerically independent columns of ``A`` (M, k) (see
    :func:`gram_factor`): Cholesky QR of the rank-revealing factor, applied twice (CholeskyQR2)
    for orthogonality to round-off. Multithreaded LAPACK QR/SVD of a tall matrix is several times
    slower than these two products (OpenBLAS). ``overwrite=True`` computes in ``A``'s own memory,
    block by block of rows (no copy of a tall matrix), and returns a view of its first columns."""
    A = np.asarray(A, dtype=float)
    if A.shape[1] == 0:
        return A
    if overwrite:
        for tol in (rtol, 0.0):
            idx, L = gram_factor(A.T @ A, tol)
            Li = lower_inverse(L)
            for a in range(0, A.shape[0], _ROWS):
                b = slice(a, a + _ROWS)
                A[b, : idx.size] = A[b][:, idx] @ Li.T
            A = A[:, : idx.size]
            if not idx.size:
                break
        return A
    idx, L = gram_factor(A.T @ A, rtol)
    if not idx.size:
        return A[:, :0]
    Q = A[:, idx] @ lower_inverse(L).T  # A L^-T, by gemm
    idx2, L2 = gram_factor(Q.T @ Q, 0.0)
    return Q[:, idx2] @ lower_inverse(L2).T


_ROWS = 3 * 4096  # rows per block of an in-place orthonormalisation


def lower_inverse(L: np.ndarray) -> np.ndarray:
    """The inverse of a small lower-triangular matrix (LAPACK ``dtrtri``; scipy's
    ``solve_triangular`` costs milliseconds per call in its Python layers)."""
    if L.size == 0:
        return np.zeros_like(L)
    inv, info = lapack.dtrtri(L, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular triangular factor (dtrtri info {info})")
    return inv
