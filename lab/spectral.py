"""The spectral scan: which cyclic joint errors a fitted model misses, every joint's orders per
turn searched at once by orthogonal matching pursuit.

    problem = problem_of_fit(result)            # the fit's linearised problem, row by row
    scan = cyclic_scan(problem, order=64, level=0.005 / M)
    scan.spec           # "cyclic[1:13,27;2:26]": what to fit
    for t in scan.terms:
        print(t.joint, t.order, t.p_value, t.alternatives)   # orders the data cannot tell apart

A cyclic joint error of order k adds ``a_s sin(k q_j) + a_c cos(k q_j)`` to joint j's angle
(the ``cyclic`` effect, ``arm.effects.Cyclic``). Orders of tens per turn are physical: whatever
turns faster than the joint repeats its error k times per output turn (a strain-wave gear twice
per turn of its wave generator, an encoder with its pole pairs, a gear stage with its teeth).

Method.

1. **The problem** (:class:`CyclicProblem`) is any weighted linear least-squares problem of a
   fit, row by row: the residual rows ``e`` (m), the model's columns ``J`` (m, p) (what the fit
   explains), each row's derivative by the joint angles ``D`` (m, 6) and the pose it belongs to
   (rows need not be three per pose: orientation rows, weights and missing rows are rows like
   any other). :func:`problem_of_fit` builds it from a :class:`lab.FitResult`.
2. **Candidates.** For every joint j and order k = 1..K_j the pair of columns ``D_j cos(k q_j)``,
   ``D_j sin(k q_j)``; K_j is ``order`` unless the sampling of joint j resolves fewer
   (:func:`resolvable_order`): a joint measured on a grid of step h cannot tell order k from
   2 pi / h - k (the orders above pi / h are aliases of lower ones: identical on the data), and a
   joint measured at n distinct angles has at most (n - 1) / 2 orders. Other functions of a
   pose (discovery's library: torques, temperature...) join as candidates of one or two
   columns (:class:`ExtraColumns`).
3. **Scoring, vectorised.** A candidate's correlation with the residual, ``x^T e = sum_n g_n
   f(q_n)`` with ``g_n`` the pose's rows of ``D_j e`` summed, is a non-uniform Fourier sum: for
   all orders of a joint one complex matrix product ``g^T exp(i k q)``. Its Gram matrix follows
   from the same sums of ``D_j^2``, and its part in the model's span from ``(Q^T X)``, kept as
   running sums: each selected term adds its columns' rows to them. No Python loop runs over
   candidates; per step the cost is one pass over the poses per joint.
4. **Selection: orthogonal matching pursuit.** Each step takes the candidate with the smallest
   p-value of the F-test of nested linear models (the residual with everything chosen so far
   projected out). It is kept when that p-value is at most ``level`` (the caller's Bonferroni
   share, ``alpha_t / M`` over the M candidates, at every step) and it lowers the
   leave-one-pose-out RMS; otherwise the scan stops. Nothing is kept unless a first step is
   significant, so on data the model explains the chance of any term is at most ``M * level``
   (lab.discovery derives the family-wise rate from it).
5. **Orders the data cannot tell apart.** At the step a term is chosen, every other candidate
   that explains as much, within the chi-square quantile (``alias_level``) of the noise left, is
   one the data cannot tell from it; on a grid-sampled joint the orders that alias the chosen
   one (``m * 2 pi / h +- k`` up to ``order``) are named too (:attr:`ScanTerm.alternatives`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse, stats

from arm.params import parameter_unit
from lab.blocks import Blocks
from lab.errors import FitError
from lab.identifiability import orthonormal_basis

__all__ = ["CyclicProblem", "CyclicScan", "cyclic_scan", "joint_sampling", "resolvable_order"]

log = logging.getLogger(__name__)

DEFAULT_ORDER = 64  # orders per turn scanned on every joint
MAX_TERMS = 40  # at most this many candidates are selected
ALIAS_LEVEL = 0.05  # the candidates within this chi-square quantile of the best are ties
_BLOCK = 4096  # poses per block of the Fourier sums (bounds the scratch memory)
_DEPENDENT = 1e-9  # a candidate's projected Gram below this share of its own: explained
_ANGLE_TOL = 1e-7  # rad: joint angles closer than this are one angle
_GRID_TOL = 1e-3  # a spacing within this share of a multiple of the grid step is on the grid


# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CyclicProblem:
    """A fit's linear least-squares problem, row by row (all arrays weighted alike).

    ``residual`` (m,): the residual rows; ``model`` (m, p): the model's (identifiable) columns,
    whose span the fit explains (``orthonormal``: they are orthonormal already, and the scan
    uses them as they are, without a copy); ``joint`` (m, 6): each row's derivative by the
    effective joint angles theta_1..6; ``pose`` (m,): the pose of each row, 0..N-1; ``q`` (N,
    6): the joint angles (rad) of each pose."""

    residual: np.ndarray
    model: np.ndarray
    joint: np.ndarray
    pose: np.ndarray
    q: np.ndarray
    orthonormal: bool = False

    def __post_init__(self) -> None:
        m = self.residual.shape[0]
        if self.model.shape[0] != m or self.joint.shape != (m, 6) or self.pose.shape != (m,):
            raise FitError(
                f"rows disagree: residual {self.residual.shape}, model {self.model.shape}, "
                f"joint {self.joint.shape}, pose {self.pose.shape}"
            )
        if self.q.ndim != 2 or self.q.shape[1] != 6:
            raise FitError(f"q must be (N, 6), got {self.q.shape}")
        if m and (self.pose.min() < 0 or self.pose.max() >= self.q.shape[0]):
            raise FitError("pose indices must lie within 0..N-1")

    @property
    def n_poses(self) -> int:
        return self.q.shape[0]


def problem_of_fit(result) -> CyclicProblem:
    """The problem of a :class:`lab.FitResult`: its residual rows, an orthonormal basis of its
    identifiable Jacobian columns and d point / d theta at the fitted parameters, three rows
    (x, y, z) per pose."""
    n = result.n_points
    free = np.flatnonzero(result.identifiable)
    scale = result.identifiability.scale[free]
    # the fit's rows: three a pose, or its weighted rows (orientations too: lab.observations)
    obs = result.observations if result.weighted else None
    k = 3 if obs is None else obs.per_pose
    J = np.empty((k * n, free.size))  # block by block: no copy of the whole Jacobian
    Jq = np.empty((n, k, 6))
    blocks = Blocks(result.model, result.inputs, observations=obs)
    for sl, _, Jb in blocks.jacobians(result.params, keep_cache=False):
        J[k * sl.start : k * sl.stop] = Jb[:, :, free].reshape(-1, free.size) * scale
    for sl, part in blocks:
        if obs is None:
            Jq[sl] = result.model.joint_jacobian(part, result.params)[1]
        else:
            Jq[sl] = obs.joint_rows(result.model, part, result.params, sl)
    return CyclicProblem(
        residual=np.asarray(result.row_residuals, dtype=float).reshape(-1),
        model=orthonormal_basis(J, overwrite=True),
        joint=Jq.reshape(k * n, 6),
        pose=np.repeat(np.arange(n), k),
        q=np.asarray(result.inputs.q, dtype=float),
        orthonormal=True,
    )


@dataclass(frozen=True)
class ExtraColumns:
    """Candidates other than the harmonics, on joint ``joint``: ``values`` (N, c) per-pose
    functions f (a column is ``D_joint * f``), grouped into candidates of one or two columns by
    ``groups`` (column indices) named by ``keys``."""

    joint: int
    values: np.ndarray
    groups: tuple[tuple[int, ...], ...]
    keys: tuple[str, ...]


# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class JointSampling:
    """How a joint was sampled: ``distinct`` angles; ``grid`` the step (rad) of the lattice its
    angles lie on, or None; ``resolvable`` the highest order the sampling can tell from the
    others (see :func:`resolvable_order`)."""

    joint: int
    distinct: int
    span: float
    grid: float | None
    resolvable: int

    def aliases(self, k: int, order: int) -> list[int]:
        """The orders up to ``order`` that are identical to order ``k`` on this joint's grid."""
        if self.grid is None:
            return []
        period = 2.0 * math.pi / self.grid  # orders per turn that the grid cannot see
        out: set[int] = set()
        for m in range(1, int((order + k) / period) + 2):
            for a in (m * period - k, m * period + k):
                if abs(a - round(a)) < 1e-6 * period and 1 <= round(a) <= order:
                    out.add(round(a))
        out.discard(k)
        return sorted(out)

    def note(self) -> str | None:
        """A sentence on what the sampling cannot resolve, or None."""
        if self.grid is not None:
            return (
                f"joint {self.joint} was measured on a grid of {math.degrees(self.grid):.4g} deg "
                f"({self.distinct} angles): orders above {self.resolvable} per turn are aliases "
                "of lower ones there"
            )
        if self.distinct < 2:
            return f"joint {self.joint} did not move: no order of it can be seen"
        return None


def _float_gcd(values: np.ndarray, tol: float, floor: float) -> float | None:
    """The largest step h whose whole multiples all ``values`` (positive) are, within ``tol``:
    Euclid's algorithm with a tolerance; None once h falls to ``floor`` or below."""
    h = float(values[0])
    for v in values[1:]:
        a, b = max(h, float(v)), min(h, float(v))
        while b > tol:
            r = math.fmod(a, b)
            a, b = b, (0.0 if r < tol or b - r < tol else r)
        h = a
        if h <= floor:
            return None
    return h


def joint_sampling(q: np.ndarray, joint: int, order: int) -> JointSampling:
    """The sampling of joint ``joint`` (1..6) in ``q`` (N, 6): its distinct angles, a grid it
    lies on (when that limits the orders below ``order``) and the highest order it resolves."""
    v = np.unique(np.round(q[:, joint - 1] / _ANGLE_TOL).astype(np.int64))
    distinct = len(v)
    span = float((v[-1] - v[0]) * _ANGLE_TOL) if distinct else 0.0
    res = max(0, (distinct - 1) // 2)
    grid = None
    if distinct >= 3:
        d = np.diff(v).astype(float) * _ANGLE_TOL
        # a grid matters where its step h is coarser than the scan's orders: pi / h < order
        h = _float_gcd(np.unique(d), 4 * _ANGLE_TOL, math.pi / order)
        if h is not None and np.all(np.abs(d / h - np.round(d / h)) < _GRID_TOL):
            grid = h
            res = min(res, math.floor(math.pi / h - 1e-9))
    return JointSampling(joint, distinct, span, grid, min(res, order) if distinct > 1 else 0)


def resolvable_order(q: np.ndarray, joint: int, order: int = DEFAULT_ORDER) -> int:
    """The highest order (at most ``order``) that the sampling of joint ``joint`` resolves: on a
    grid of step h, pi / h (higher orders alias lower ones); with n distinct angles, (n - 1) / 2;
    0 for a joint that did not move."""
    return joint_sampling(q, joint, order).resolvable


# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ScanTerm:
    """One selected candidate: on ``joint``, the harmonic of ``order`` (``key`` None) or an extra
    candidate ``key``; its F-test ``p_value`` when chosen (unadjusted), the residual sum of
    squares it explained, the RMS and leave-one-pose-out RMS after it (per pose), and the
    ``alternatives``: (joint, order or key) the data cannot tell from it."""

    joint: int
    order: int | None
    key: str | None
    p_value: float
    explained: float
    rms_after: float
    cv_after: float
    alternatives: tuple[tuple[int, int | str], ...] = ()

    @property
    def label(self) -> str:
        return f"q{self.joint} order {self.order}" if self.order is not None else f"{self.key}"


@dataclass
class CyclicScan:
    """What :func:`cyclic_scan` found: the ``terms`` in the order chosen, the number of
    candidates (``n_candidates``, M), the orders scanned per joint and how each was sampled,
    the residual sum of squares and degrees of freedom before and after, the leave-one-pose-out
    RMS before and after, and the smallest first-step p-value (unadjusted)."""

    terms: list[ScanTerm]
    n_candidates: int
    orders: dict[int, int]
    sampling: dict[int, JointSampling]
    rss0: float
    dof0: int
    rss: float
    dof: int
    cv0: float
    cv: float
    first_p: float
    level: float
    residual: np.ndarray = field(repr=False)
    # candidates passed over: with them, a parameter would go beyond its plausible bound
    implausible: list[str] = field(default_factory=list)
    # why the scan stopped (CyclicScanner.stop)
    stop: str | None = None
    # the linearised estimate of every parameter chosen (CyclicScanner.estimates)
    estimates: dict[str, float] = field(default_factory=dict)

    @property
    def exhausted(self) -> bool:
        """Whether no candidate is left that the residual significantly depends on (the scan
        did not stop at ``max_terms``)."""
        return self.stop in ("not significant", "no better held-out", "no candidates")

    @property
    def harmonics(self) -> dict[int, list[int]]:
        """The selected orders of each joint, ascending."""
        out: dict[int, list[int]] = {}
        for t in self.terms:
            if t.order is not None:
                out.setdefault(t.joint, []).append(t.order)
        return {j: sorted(ks) for j, ks in sorted(out.items())}

    @property
    def spec(self) -> str | None:
        """The ``cyclic[...]`` effect of the selected harmonics, or None."""
        h = self.harmonics
        if not h:
            return None
        return "cyclic[" + ";".join(f"{j}:{','.join(map(str, ks))}" for j, ks in h.items()) + "]"

    def notes(self) -> list[str]:
        """Sentences on what the sampling of the joints cannot resolve."""
        return [n for s in self.sampling.values() if (n := s.note()) is not None]


# --------------------------------------------------------------------------------------------------
class _Layout:
    """Rows grouped by pose: sums over each pose's rows and the padded (N, R) slots of the
    leave-one-pose-out blocks. Rows that come R to a pose, in order (a fit's x, y, z), are
    regular: views and reshapes then, no index arrays."""

    def __init__(self, pose: np.ndarray, n: int) -> None:
        m = len(pose)
        self.n = n
        counts = np.bincount(pose, minlength=n)
        self.R = int(counts.max()) if m else 0
        self.regular = bool(
            m == n * self.R and np.all(counts == self.R) and np.all(np.diff(pose) >= 0)
        )
        self.pose = pose
        if self.regular:
            return
        self.sum = sparse.csr_matrix((np.ones(m), (pose, np.arange(m))), shape=(n, m))
        order = np.argsort(pose, kind="stable")
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        slot = np.empty(m, dtype=int)
        slot[order] = np.arange(m) - np.repeat(start, counts)
        self.slot = slot

    def pad(self, x: np.ndarray) -> np.ndarray:
        """Rows (m, ...) as (N, R, ...), zero where a pose has fewer rows (a view if regular)."""
        if self.regular:
            return x.reshape(self.n, self.R, *x.shape[1:])
        out = np.zeros((self.n, self.R, *x.shape[1:]))
        out[self.pose, self.slot] = x
        return out

    def per_pose(self, x: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
        """Sum over each pose's rows of ``x`` (m,) or (m, k), times ``w`` (m,) if given;
        block by block (no (m, k) product is made)."""
        if not self.regular:
            return np.asarray(self.sum @ (x if w is None else (w * x.T).T))
        out = np.empty((self.n, *x.shape[1:]))
        for s in range(0, self.n, _BLOCK):
            sl = slice(s, min(s + _BLOCK, self.n))
            rows = slice(self.R * sl.start, self.R * sl.stop)
            xb = x[rows] if w is None else (w[rows] * x[rows].T).T
            out[sl] = xb.reshape(sl.stop - sl.start, self.R, *x.shape[1:]).sum(axis=1)
        return out


def _powers(z: np.ndarray, K: int) -> np.ndarray:
    """(n, K): z, z^2, ..., z^K, by doubling (log2 K products of blocks)."""
    Z = np.empty((len(z), K), dtype=complex)
    Z[:, 0] = z
    n = 1
    while n < K:
        m = min(n, K - n)
        np.multiply(Z[:, :m], Z[:, n - 1 : n], out=Z[:, n : n + m])
        n += m
    return Z


def _hat(Qp: np.ndarray) -> np.ndarray:
    return np.matmul(Qp, Qp.transpose(0, 2, 1))


def _loo_rms(e_pad: np.ndarray, H: np.ndarray) -> float:
    """Leave-one-pose-out RMS per pose: e_(-n) = (I - H_nn)^-1 e_n."""
    n, R = e_pad.shape
    loo = np.linalg.solve(np.eye(R) - H, e_pad[:, :, None])[:, :, 0]
    return float(np.sqrt(np.sum(loo**2) / max(n, 1)))


class _Candidates:
    """The running statistics of every candidate (flat arrays over all of them): per candidate
    columns a and b (b absent for a single column), their Gram entries, the same restricted to
    the span chosen so far, and their correlations with the residual."""

    def __init__(
        self,
        prob: CyclicProblem,
        lay: _Layout,
        orders: dict[int, int],
        extras: Sequence[ExtraColumns],
    ) -> None:
        self.prob, self.lay, self.orders = prob, lay, orders
        self.extras = {j: [x for x in extras if x.joint == j] for j in range(1, 7)}
        self.z = np.exp(1j * prob.q)  # (N, 6): the first harmonic of every joint
        self._extra_at: dict[int, int] = {}  # where each extra's columns start, per joint
        for j in range(1, 7):
            at = 0
            for x in self.extras[j]:
                self._extra_at[id(x)] = at
                at += x.values.shape[1]
        joint: list[int] = []
        order: list[int | None] = []
        key: list[str | None] = []
        ia: list[int] = []
        ib: list[int] = []
        self.offset: dict[int, int] = {}  # where each joint's columns start (harmonics first)
        self.ncols: dict[int, int] = {}
        col = 0
        for j in range(1, 7):
            K = orders.get(j, 0)
            self.offset[j] = col
            ks = np.arange(1, K + 1)
            joint += [j] * K
            order += [int(k) for k in ks]
            key += [None] * K
            ia += (col + ks - 1).tolist()  # cos(k q)
            ib += (col + K + ks - 1).tolist()  # sin(k q)
            c = col + 2 * K
            for x in self.extras[j]:
                for g, name in zip(x.groups, x.keys, strict=True):
                    joint.append(j)
                    order.append(None)
                    key.append(name)
                    ia.append(c + g[0])
                    ib.append(c + g[1] if len(g) > 1 else -1)
                c += x.values.shape[1]
            self.ncols[j] = c - col
            col = c
        self.joint = np.array(joint, dtype=int)
        self.order = order
        self.key = key
        self.ia = np.array(ia, dtype=int)
        self.ib = np.array(ib, dtype=int)
        self.total = col
        # per column: Gram diagonal, and per candidate the cross term; the projected parts
        self.G = np.zeros(col)
        self.Gab = np.zeros(len(joint))
        self.S = np.zeros(col)
        self.Sab = np.zeros(len(joint))
        self.c = np.zeros(col)

    def __len__(self) -> int:
        return len(self.joint)

    # -- the per-pose functions of a joint, block by block ---------------------------------------
    def functions(self, j: int, sl: slice) -> np.ndarray:
        """(n, columns of joint j): cos(k q), sin(k q) for k = 1..K_j, then the extras."""
        K = self.orders.get(j, 0)
        qj = self.prob.q[sl, j - 1]
        parts = []
        if K:
            Z = _powers(self.z[sl, j - 1], K)
            parts += [Z.real, Z.imag]
        parts += [x.values[sl] for x in self.extras[j]]
        return np.hstack(parts) if parts else np.zeros((len(qj), 0))

    def project(self, A: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
        """Per joint j, ``A[j]^T F_j`` ((k, columns)) for per-pose weights A[j] (N, k): the
        harmonics as one complex product (a non-uniform Fourier sum), block by block."""
        out = {}
        for j, a in A.items():
            K = self.orders.get(j, 0)
            acc = np.zeros((a.shape[1], self.ncols[j]))
            h = np.zeros((a.shape[1], K), dtype=complex)
            for s in range(0, self.lay.n, _BLOCK):
                sl = slice(s, s + _BLOCK)
                if K:
                    h += a[sl].T @ _powers(self.z[sl, j - 1], K)
                for x in self.extras[j]:
                    c = 2 * K + self._extra_at[id(x)]
                    acc[:, c : c + x.values.shape[1]] += a[sl].T @ x.values[sl]
            acc[:, :K], acc[:, K : 2 * K] = h.real, h.imag
            out[j] = acc
        return out

    def initialise(self, Q: np.ndarray, e: np.ndarray) -> None:
        prob, lay = self.prob, self.lay
        D = prob.joint
        for j in range(1, 7):
            if not self.ncols[j]:
                continue
            w = lay.per_pose(D[:, j - 1] ** 2)  # (N,)
            g = lay.per_pose(D[:, j - 1] * e)
            A = lay.per_pose(Q, D[:, j - 1])  # (N, r)
            o, n = self.offset[j], self.ncols[j]
            sel = (self.joint == j) & (self.ib >= 0)
            pa, pb = self.ia[sel] - o, self.ib[sel] - o
            G = np.zeros(n)
            Gab = np.zeros(int(sel.sum()))
            c = np.zeros(n)
            P = np.zeros((A.shape[1], n))  # Q^T X of the joint's columns
            for s in range(0, lay.n, _BLOCK):
                sl = slice(s, s + _BLOCK)
                F = self.functions(j, sl)
                G += w[sl] @ F**2
                Gab += w[sl] @ (F[:, pa] * F[:, pb])
                P += A[sl].T @ F
                c += g[sl] @ F
            self.G[o : o + n] = G
            self.S[o : o + n] = np.sum(P**2, axis=0)
            self.c[o : o + n] = c
            self.Gab[sel] = Gab
            self.Sab[sel] = np.sum(P[:, pa] * P[:, pb], axis=0)

    def add(self, Qn: np.ndarray, b: np.ndarray) -> None:
        """New orthonormal columns ``Qn`` (m, k) joined the span; ``b = Qn^T e`` before the
        residual lost them: the statistics follow."""
        D = self.prob.joint
        A = {j: self.lay.per_pose(Qn, D[:, j - 1]) for j in range(1, 7) if self.ncols[j]}
        P = self.project(A)
        for j, Pj in P.items():
            o, n = self.offset[j], self.ncols[j]
            self.S[o : o + n] += np.sum(Pj**2, axis=0)
            self.c[o : o + n] -= b @ Pj
            sel = (self.joint == j) & (self.ib >= 0)
            self.Sab[sel] += np.sum(Pj[:, self.ia[sel] - o] * Pj[:, self.ib[sel] - o], axis=0)

    def scores(self, rss: float, dof: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per candidate: explained sum of squares, degrees of freedom (0: explained already)
        and the F-test's p-value."""
        ia, ib = self.ia, self.ib
        pair = ib >= 0
        ibs = np.where(pair, ib, ia)
        Ga, Gb = self.G[ia], np.where(pair, self.G[ibs], 1.0)
        Paa = Ga - self.S[ia]
        Pbb = np.where(pair, Gb - self.S[ibs], 1.0)
        Pab = np.where(pair, self.Gab - self.Sab, 0.0)
        ca = self.c[ia]
        cb = np.where(pair, self.c[ibs], 0.0)
        M = np.stack([np.stack([Paa, Pab], -1), np.stack([Pab, Pbb], -1)], -2)
        lam, V = np.linalg.eigh(M)  # ascending, (L, 2), (L, 2, 2)
        ref = np.stack([Ga, Gb], -1).max(axis=-1)
        keep = lam > _DEPENDENT * ref[:, None]
        keep[~pair, :] &= np.abs(V[~pair, 0, :]) > 0.5  # a single column: its own direction
        proj = V[:, 0, :] * ca[:, None] + V[:, 1, :] * cb[:, None]  # (L, 2): v^T c
        ss = np.sum(np.where(keep, proj**2 / np.where(keep, lam, 1.0), 0.0), axis=1)
        k = keep.sum(axis=1)
        ss = np.minimum(ss, rss)
        ok = (k > 0) & (dof - k > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            F = (ss / np.maximum(k, 1)) / ((rss - ss) / np.maximum(dof - k, 1))
        p = np.where(
            ok, stats.f.sf(np.where(ok, F, 0.0), np.maximum(k, 1), np.maximum(dof - k, 1)), 1.0
        )
        return np.where(ok, ss, 0.0), np.where(ok, k, 0), p

    def values(self, i: int, rows: slice = slice(None)) -> np.ndarray:
        """The candidate's per-row functions (rows, 1 or 2): cos(k q), sin(k q) of a harmonic,
        an extra's values."""
        j = int(self.joint[i])
        pose = self.prob.pose[rows]
        k = self.order[i]
        if k is not None:
            angle = k * self.prob.q[pose, j - 1]
            return np.column_stack([np.cos(angle), np.sin(angle)])
        o = self.offset[j] + 2 * self.orders.get(j, 0)
        cols = [self.ia[i] - o] + ([self.ib[i] - o] if self.ib[i] >= 0 else [])
        values = np.hstack([x.values for x in self.extras[j]])
        return values[pose][:, cols]

    def columns(self, i: int, rows: slice = slice(None)) -> np.ndarray:
        """The candidate's columns (rows, 1 or 2), explicitly: D_j times its functions."""
        j = int(self.joint[i])
        return self.prob.joint[rows, j - 1 : j] * self.values(i, rows)


@dataclass(frozen=True)
class Prior:
    """Columns already in the explanation beside the model (a diagnosis's catalogued effects):
    ``columns`` (m, p) raw or with the model's span projected out (the same coefficients, by
    Frisch-Waugh-Lovell), their parameters' ``names``, ``nominal`` values and plausible
    ``bounds`` (NaN: none)."""

    columns: np.ndarray
    names: tuple[str, ...]
    nominal: np.ndarray
    bounds: np.ndarray


class _Explanation:
    """The columns chosen beside the model, Y (m, p), as orthonormal blocks ``Qall`` (each m x k,
    the model's span and the blocks before projected out) and the triangular factor ``R`` with
    Y (model's span projected out) = Qall R; ``c = Qall^T e0``; the parameters' names, nominal
    values and plausible bounds. The linearised estimate of every parameter is nominal minus
    ``lstsq(R, c)``, from these small matrices alone."""

    def __init__(self, Q0: np.ndarray, e0: np.ndarray) -> None:
        self.Q0, self.e0 = Q0, e0
        self.blocks: list[np.ndarray] = []
        self.R = np.zeros((0, 0))
        self.c = np.zeros(0)
        self.names: list[str] = []
        self.nominal: list[float] = []
        self.bounds: list[float] = []

    def _against(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x minus its projections on the model's span and the blocks (in x's memory), and its
        coefficients on the blocks (q, k)."""
        x -= self.Q0 @ (self.Q0.T @ x)
        r = [B.T @ x for B in self.blocks]
        for B, rb in zip(self.blocks, r, strict=True):
            x -= B @ rb
        return x, np.vstack(r) if r else np.zeros((0, x.shape[1]))

    def trial(self, X: np.ndarray):
        """New raw columns ``X`` (m, k): their orthonormal block with everything chosen
        projected out, the factors that add them, and the coefficients of Y and X fitting e0."""
        x, r = self._against(np.array(X, dtype=float))
        x, r2 = self._against(x)  # twice is enough (Gram-Schmidt)
        r = r + r2
        Qn = orthonormal_basis(x.copy(), overwrite=True)
        Rnn = Qn.T @ x
        q, p = self.R.shape
        R = np.zeros((q + Qn.shape[1], p + X.shape[1]))
        R[:q, :p] = self.R
        R[:q, p:] = r
        R[q:, p:] = Rnn
        c = np.concatenate([self.c, Qn.T @ self.e0])
        coef = np.linalg.lstsq(R, c, rcond=1e-12)[0]
        return Qn, R, c, coef

    def add(self, Qn: np.ndarray, R: np.ndarray, c: np.ndarray, names, nominal, bounds) -> None:
        if Qn.shape[1]:
            self.blocks.append(Qn)
        self.R, self.c = R, c
        self.names += list(names)
        self.nominal += [float(v) for v in nominal]
        self.bounds += [float(b) for b in bounds]

    def beyond(self, coef: np.ndarray, names, bounds, nominal) -> list[str]:
        """``name = value (bound)`` of the parameters beyond their bound, the linearised
        estimate being nominal minus the coefficient (the fit steps against the residual)."""
        allnames = self.names + list(names)
        values = np.array(self.nominal + [float(v) for v in nominal]) - coef
        bound = np.array(self.bounds + [float(b) for b in bounds], dtype=float)
        bad = np.flatnonzero(np.isfinite(bound) & (np.abs(values) > bound))
        out = []
        for k in bad:
            unit = parameter_unit(allnames[k])
            if unit == "rad":
                out.append(
                    f"{allnames[k]} = {values[k] * 1e3:+.4g} mrad (bound {bound[k] * 1e3:g} mrad)"
                )
            else:
                out.append(f"{allnames[k]} = {values[k]:+.4g} {unit} (bound {bound[k]:.3g})")
        return out


@dataclass
class Proposal:
    """The scan's next term, tried but not yet taken: candidate ``index``, its columns with
    everything chosen projected out (``basis``, orthonormal), the residual and hat blocks after
    it, its F-test p-value, and what :meth:`CyclicScanner.accept` needs."""

    index: int
    basis: np.ndarray
    residual: np.ndarray
    hat: np.ndarray
    cv: float
    p_value: float
    ss: float
    k: int
    factors: tuple[np.ndarray, np.ndarray]
    names: list[str]
    bounds: list[float]
    coef: np.ndarray


class CyclicScanner:
    """The scan as a sequence of steps (:func:`cyclic_scan` runs them to the end): ``propose``
    the next term, ``accept`` it; columns chosen elsewhere (a diagnosis's catalogued effects) join
    the explanation with ``add_columns``, and ``implausible`` says what a set of columns would do
    to the plausibility of the explanation. See :func:`cyclic_scan` for the arguments."""

    def __init__(
        self,
        problem: CyclicProblem,
        order: int = DEFAULT_ORDER,
        level: float | None = None,
        *,
        alpha: float = 0.02,
        extras: Sequence[ExtraColumns] = (),
        joints: Sequence[int] = (1, 2, 3, 4, 5, 6),
        max_terms: int = MAX_TERMS,
        alias_level: float = ALIAS_LEVEL,
        prior: Prior | None = None,
        bound: float | None = None,
    ) -> None:
        if order < 1:
            raise FitError(f"order must be at least 1, got {order}")
        prob = problem
        self.prob, self.order, self.max_terms = prob, order, max_terms
        self.alias_level, self.bound = alias_level, bound
        n = self.n = prob.n_poses
        self.lay = lay = _Layout(prob.pose, n)
        self.sampling = {j: joint_sampling(prob.q, j, order) for j in range(1, 7)}
        moves = np.sqrt(np.sum(prob.joint**2, axis=0) / max(n, 1))
        self.orders = {
            j: (self.sampling[j].resolvable if j in joints and moves[j - 1] > 0 else 0)
            for j in range(1, 7)
        }
        Q0 = prob.model
        if not prob.orthonormal:
            Q0 = orthonormal_basis(np.array(prob.model), overwrite=True)
        e0 = prob.residual - Q0 @ (Q0.T @ prob.residual)
        self.cand = _Candidates(prob, lay, self.orders, extras)
        self.cand.initialise(Q0, e0)
        self.expl = _Explanation(Q0, e0)
        self.e = e0
        self.H = _hat(lay.pad(Q0))
        self.dof = len(e0) - Q0.shape[1]
        self.rss = float(e0 @ e0)
        if prior is not None and prior.columns.shape[1]:
            self.add_columns(prior.columns, list(prior.names), prior.nominal, prior.bounds)
        self.rss0, self.dof0 = self.rss, self.dof
        self.cv = self.cv0 = _loo_rms(lay.pad(self.e), self.H)
        self._scores: tuple[np.ndarray, np.ndarray, np.ndarray] | None = self.cand.scores(
            self.rss, self.dof
        )
        _, k, p = self._scores
        self.M = int(np.count_nonzero(k))
        self.level = float(alpha / max(self.M, 1) if level is None else level)
        self.first_p = float(p.min()) if len(p) else 1.0
        self.terms: list[ScanTerm] = []
        self.implausible_terms: list[str] = []
        self.done: set[int] = set()
        self.coef: np.ndarray = np.zeros(
            0
        )  # the explanation's coefficients on e0, in its names' order
        # why the last proposal was none: "not significant", "no better held-out",
        # "max_terms" or "no candidates"
        self.stop: str | None = None

    # -- the explanation ------------------------------------------------------------------------
    def _step(self, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        b = basis.T @ self.e
        return b, self.e - basis @ b, self.H + _hat(self.lay.pad(basis))

    def add_columns(
        self, X: np.ndarray, names: list[str], nominal: np.ndarray, bounds: np.ndarray
    ) -> None:
        """Columns ``X`` (m, k) (raw, or with the model's span projected out) chosen elsewhere
        join the explanation, with their parameters' names, nominal values and bounds."""
        Qn, R, c, _ = self.expl.trial(X)
        self.expl.add(Qn, R, c, names, nominal, bounds)
        if Qn.shape[1]:
            b, self.e, self.H = self._step(Qn)
            self.cand.add(Qn, b)
            self.dof -= Qn.shape[1]
            self.rss = float(self.e @ self.e)
        self.cv = _loo_rms(self.lay.pad(self.e), self.H)
        self._scores = None

    def implausible(self, X: np.ndarray, names: list[str], nominal, bounds) -> list[str]:
        """The parameters of the explanation and of columns ``X`` beyond their bounds, at the
        linearised estimate of the explanation with ``X``."""
        coef = self.expl.trial(X)[3]
        return self.expl.beyond(coef, names, bounds, nominal)

    # -- the steps ------------------------------------------------------------------------------
    def propose(self) -> Proposal | None:
        """The next term: among the candidates not yet taken, the smallest p-value whose
        parameters stay plausible; None when it is not significant at the level, does not lower
        the leave-one-pose-out RMS, or the scan has its ``max_terms``."""
        if len(self.terms) >= self.max_terms:
            self.stop = "max_terms"
            return None
        if not len(self.cand):
            self.stop = "no candidates"
            return None
        cand = self.cand
        while True:
            if self._scores is None:
                self._scores = cand.scores(self.rss, self.dof)
            ss, k, p = self._scores
            p = p.copy()
            p[list(self.done)] = 1.0
            i = int(np.lexsort((-ss, p))[0])  # the smallest p-value, the largest ss among ties
            if not (k[i] > 0 and p[i] <= self.level):
                self.stop = "not significant"
                return None
            j, o_i = int(cand.joint[i]), cand.order[i]
            x = cand.columns(i)
            if o_i is not None:  # the columns are cos(k q), sin(k q): amplitudes cc, cs
                names = [f"cc{j}_{o_i}", f"cs{j}_{o_i}"]
            else:
                names = [f"{cand.key[i]}:{c}" for c in range(x.shape[1])]
            use = self.bound is not None and o_i is not None
            bounds = [float(self.bound) if use else np.nan] * x.shape[1]  # type: ignore[arg-type]
            Qn, R, c, coef = self.expl.trial(x)
            bad = self.expl.beyond(coef, names, bounds, [0.0] * len(names))
            if bad:
                label = f"cyclic[{j}:{o_i}]" if o_i is not None else f"{cand.key[i]}"
                self.implausible_terms.append(f"{label}: {', '.join(bad)}")
                self.done.add(i)
                continue
            if Qn.shape[1] == 0:
                self.done.add(i)
                continue
            _, e_new, H_new = self._step(Qn)
            cv_new = _loo_rms(self.lay.pad(e_new), H_new)
            if not cv_new < self.cv:
                self.stop = "no better held-out"
                return None
            return Proposal(
                i,
                Qn,
                e_new,
                H_new,
                cv_new,
                float(p[i]),
                float(ss[i]),
                int(k[i]),
                (R, c),
                names,
                bounds,
                coef,
            )

    def accept(self, pr: Proposal) -> ScanTerm:
        """Take a proposed term."""
        cand, i = self.cand, pr.index
        ss, k, _ = self._scores if self._scores is not None else cand.scores(self.rss, self.dof)
        j, o_i = int(cand.joint[i]), cand.order[i]
        # the candidates the data cannot tell from this one, at this step
        s2 = (self.rss - pr.ss) / max(self.dof - pr.k, 1)
        tie = ss >= pr.ss - s2 * stats.chi2.ppf(1.0 - self.alias_level, max(pr.k, 1))
        tie[i] = False
        tie &= k > 0
        alts: list[tuple[int, int | str]] = []
        for t in np.flatnonzero(tie):
            o_t = cand.order[t]
            alts.append((int(cand.joint[t]), o_t if o_t is not None else str(cand.key[t])))
        if o_i is not None:
            alts += [(j, a) for a in self.sampling[j].aliases(o_i, self.order)]
        rss_new = float(pr.residual @ pr.residual)
        term = ScanTerm(
            joint=j,
            order=o_i,
            key=cand.key[i],
            p_value=pr.p_value,
            explained=self.rss - rss_new,
            rms_after=math.sqrt(rss_new / max(self.n, 1)),
            cv_after=pr.cv,
            alternatives=tuple(dict.fromkeys(alts)),
        )
        self.terms.append(term)
        log.debug("scan: %s (p = %.3g, %d alternatives)", term.label, pr.p_value, len(alts))
        cand.add(pr.basis, pr.basis.T @ self.e)
        R, c = pr.factors
        self.expl.add(pr.basis, R, c, pr.names, [0.0] * len(pr.names), pr.bounds)
        self.coef = pr.coef
        self.e, self.H, self.cv, self.rss = pr.residual, pr.hat, pr.cv, rss_new
        self.dof -= pr.basis.shape[1]
        self.done.add(i)
        self._scores = None
        return term

    def result(self) -> CyclicScan:
        return CyclicScan(
            terms=list(self.terms),
            n_candidates=self.M,
            orders=self.orders,
            sampling=self.sampling,
            rss0=self.rss0,
            dof0=self.dof0,
            rss=self.rss,
            dof=self.dof,
            cv0=self.cv0,
            cv=self.cv,
            first_p=self.first_p,
            level=self.level,
            residual=self.e,
            implausible=list(self.implausible_terms),
            stop=self.stop,
            estimates=self.estimates(),
        )

    def estimates(self) -> dict[str, float]:
        """The linearised estimate of every parameter of the explanation (the given columns' by
        name, a harmonic's ``cc{j}_{k}``, ``cs{j}_{k}``, an extra's ``key:column``)."""
        if len(self.coef) != len(self.expl.names):  # columns joined since the last term
            self.coef = np.linalg.lstsq(self.expl.R, self.expl.c, rcond=1e-12)[0]
        values = np.array(self.expl.nominal) - self.coef
        return dict(zip(self.expl.names, map(float, values), strict=True))


def cyclic_scan(
    problem: CyclicProblem,
    order: int = DEFAULT_ORDER,
    level: float | None = None,
    *,
    alpha: float = 0.02,
    extras: Sequence[ExtraColumns] = (),
    joints: Sequence[int] = (1, 2, 3, 4, 5, 6),
    max_terms: int = MAX_TERMS,
    alias_level: float = ALIAS_LEVEL,
    prior: Prior | None = None,
    bound: float | None = None,
) -> CyclicScan:
    """Scan every joint's cyclic errors up to ``order`` (and the ``extras``) for what the
    problem's model (and the ``prior`` columns) miss; see the module docstring. ``level``: the
    p-value a step must reach (default ``alpha`` over the number of candidates, Bonferroni).
    ``bound``: the plausible bound of a cyclic error's amplitudes (rad, each of sine and cosine);
    a term whose linearised estimate, or the prior's, goes beyond a bound with it is passed over
    (named in :attr:`CyclicScan.implausible`), as :func:`lab.fit` would refuse it."""
    scanner = CyclicScanner(
        problem,
        order,
        level,
        alpha=alpha,
        extras=extras,
        joints=joints,
        max_terms=max_terms,
        alias_level=alias_level,
        prior=prior,
        bound=bound,
    )
    while (pr := scanner.propose()) is not None:
        scanner.accept(pr)
    return scanner.result()
