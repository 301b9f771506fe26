"""The lab's figures: matplotlib PNGs, drawn on plain :class:`~matplotlib.figure.Figure` objects
(the Agg canvas, no pyplot state), from arrays in SI units; every function returns a Figure and
:func:`png` turns one into bytes. Lengths are shown in mm, angles in mrad.

* :func:`residuals_figure`: x, y, z and 3-D residual per pose for several models (the seed
  paper's Fig. 8, before and after calibration).
* :func:`rms_figure`: RMS of each model on the fitted and on held-out poses, with the noise floor.
* :func:`hints_figure`: the residual against the measured variables it depends on most.
* :func:`sensitivity_figure`: how far a typical-size error of each parameter moves the tool point,
  and how far the identified one does (the paper's section 3.3 and Fig. 7).
* :func:`singular_values_figure`: the identification Jacobian's scaled singular values.
* :func:`candidates_figure`: the RMS that each candidate effect would leave.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import matplotlib
import numpy as np
from matplotlib.figure import Figure

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

__all__ = [
    "candidates_figure",
    "hints_figure",
    "residuals_figure",
    "rms_figure",
    "sensitivity_figure",
    "singular_values_figure",
]

# nominal grey, then the models in the order they were fitted
MODEL_COLORS = ("#8c8c8c", "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e")
_FLOOR = "#2ca02c"
_STYLE: dict[RcKeyType, Any] = {
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "legend.frameon": False,
}


def _figure(w: float, h: float) -> Figure:
    with matplotlib.rc_context(_STYLE):
        return Figure(figsize=(w, h), layout="constrained")


def _axes(fig: Figure, *args, **kw):
    with matplotlib.rc_context(_STYLE):
        return fig.subplots(*args, **kw)


def _plain_log(ax, axis: str = "x") -> None:
    """Log scale with plain numbers (0.02, 0.1, 1) instead of powers of ten."""
    from matplotlib.ticker import FuncFormatter, LogLocator

    fmt = FuncFormatter(lambda v, _: f"{v:g}")
    target = ax.xaxis if axis == "x" else ax.yaxis
    (ax.set_xscale if axis == "x" else ax.set_yscale)("log")
    target.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    target.set_major_formatter(fmt)
    target.set_minor_formatter(FuncFormatter(lambda v, _: ""))


def png(fig: Figure, dpi: int = 110) -> bytes:
    """The figure as PNG bytes (no timestamp in the metadata: the same figure, the same bytes)."""
    buf = io.BytesIO()
    with matplotlib.rc_context(_STYLE):
        fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    return buf.getvalue()


def color(k: int) -> str:
    return MODEL_COLORS[k % len(MODEL_COLORS)]


# --------------------------------------------------------------------------------------------------
def residuals_figure(
    series: Sequence[tuple[str, np.ndarray]],
    title: str = "",
    colors: Sequence[str] | None = None,
    floor_mm: float | None = None,
) -> Figure:
    """Per pose, the x, y, z residual (predicted minus measured) and its 3-D norm, in mm, one line
    per model: ``series`` is ``[(label, residuals (N, 3) in m), ...]``, the first usually the
    nominal model. The 3-D panel is on a log scale, so that a model at the noise floor (drawn at
    ``floor_mm``) stays visible beside one a hundred times worse."""
    colors = list(colors) if colors is not None else [color(k) for k in range(len(series))]
    fig = _figure(9.0, 7.2)
    axes = _axes(fig, 4, 1, sharex=True)
    n = len(series[0][1]) if series else 0
    idx = np.arange(1, n + 1)
    lw = 1.0 if n <= 120 else 0.7
    for k, (label, r) in enumerate(series):
        r = 1e3 * np.asarray(r)
        comps = (r[:, 0], r[:, 1], r[:, 2], np.linalg.norm(r, axis=1))
        for ax, v in zip(axes, comps, strict=True):
            ax.plot(idx, v, color=colors[k], lw=lw, marker="o", ms=2.0, label=label, alpha=0.9)
    for ax, name in zip(axes, ("x", "y", "z", "3-D"), strict=True):
        ax.set_ylabel(f"{name} error (mm)")
        if name != "3-D":
            ax.axhline(0.0, color="black", lw=0.6)
    _plain_log(axes[3], "y")
    if floor_mm:
        axes[3].axhline(floor_mm, color=_FLOOR, ls="--", lw=1.0, label="noise floor")
    axes[3].set_xlabel("pose")
    axes[0].legend(loc="upper right", ncol=min(len(series), 4))
    if title:
        fig.suptitle(title)
    return fig


def rms_figure(
    labels: Sequence[str],
    rms_mm: Sequence[float],
    validation_rms_mm: Sequence[float | None] | None = None,
    floor_mm: float | None = None,
) -> Figure:
    """RMS of each model on the fitted poses (and held-out poses), log scale, with the noise
    floor sigma*sqrt(3) of a perfect model on held-out poses."""
    fig = _figure(9.0, 1.3 + 0.5 * len(labels))
    ax = _axes(fig)
    y = np.arange(len(labels))[::-1]
    has_val = validation_rms_mm is not None and any(v is not None for v in validation_rms_mm)
    h = 0.38 if has_val else 0.6
    ax.barh(
        y + (h / 2 if has_val else 0),
        rms_mm,
        height=h,
        color=[color(k) for k in range(len(labels))],
        label="fitted poses",
    )
    for yy, v in zip(y, rms_mm, strict=True):
        ax.text(v, yy + (h / 2 if has_val else 0), f" {v:.4f}", va="center", fontsize=8)
    if has_val and validation_rms_mm is not None:
        vals = [np.nan if v is None else v for v in validation_rms_mm]
        ax.barh(
            y - h / 2,
            vals,
            height=h,
            color=[color(k) for k in range(len(labels))],
            alpha=0.45,
            hatch="//",
            label="held-out poses",
        )
        for yy, v in zip(y, vals, strict=True):
            if np.isfinite(v):
                ax.text(v, yy - h / 2, f" {v:.4f}", va="center", fontsize=8)
    if floor_mm:
        ax.axvline(floor_mm, color=_FLOOR, ls="--", lw=1.2, label=f"noise floor {floor_mm:.4f} mm")
    _plain_log(ax)
    ax.set_yticks(y, labels)
    ax.set_xlabel("3-D RMS error (mm, log scale)")
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=3)
    ax.grid(axis="y", visible=False)
    return fig


@dataclass
class HintPanel:
    """One panel of :func:`hints_figure`: a variable ``x`` and, per model, the residual projected
    on the direction that depends on it most (``y``: mm or mrad), with a smooth fit."""

    variable: str
    x_label: str
    y_label: str
    score: float
    series: list[tuple[str, np.ndarray, np.ndarray, np.ndarray | None]]  # label, x, y, fitted y
    discrete: bool = False


def hints_figure(panels: Sequence[HintPanel], colors: Sequence[str] | None = None) -> Figure:
    """The residual against each hinted variable, one panel each, the first and the last model
    overlaid: a dependence that the model misses shows as a trend that the better model removes."""
    n = max(len(panels), 1)
    fig = _figure(min(3.3 * n, 10.0), 3.2)
    axes = np.atleast_1d(_axes(fig, 1, n, squeeze=False)[0])
    for ax, p in zip(axes, panels, strict=False):
        for k, (label, x, y, yfit) in enumerate(p.series):
            c = colors[k] if colors is not None else color(k)
            xs = x
            if p.discrete:  # +-1 directions, target ids: spread the points
                xs = x + np.linspace(-0.15, 0.15, len(x))[np.argsort(np.argsort(y))]
            ax.scatter(xs, y, s=6, color=c, alpha=0.55, lw=0, label=label)
            if yfit is not None:
                o = np.argsort(x)
                ax.plot(x[o], yfit[o], color=c, lw=1.6)
        ax.axhline(0.0, color="black", lw=0.6)
        ax.set_xlabel(p.x_label)
        ax.set_ylabel(p.y_label)
        ax.set_title(f"{p.variable} (score {p.score:.2f})")
    if panels:
        axes[0].legend(loc="best", markerscale=2.5)
    return fig


def sensitivity_figure(
    names: Sequence[str],
    typical_mm: np.ndarray,
    units: Sequence[str],
    identified_mm: np.ndarray | None = None,
    identifiable: np.ndarray | None = None,
) -> Figure:
    """The error-factor analysis (the seed paper's section 3.3, Fig. 7) as one ranking: how far
    an error of each parameter's typical size moves the tool point (RMS over the poses, mm; bars,
    angles red, lengths blue, other effects grey) and, as dots, how far the error identified on
    this arm does. Parameters the data cannot identify are hatched."""
    typical_mm = np.asarray(typical_mm, dtype=float)
    ok = np.ones(len(names), dtype=bool) if identifiable is None else np.asarray(identifiable)
    order = np.argsort(-typical_mm, kind="stable")
    fig = _figure(9.0, 1.2 + 0.17 * len(names))
    ax = _axes(fig)
    y = np.arange(len(order))[::-1]
    family = {"rad": "#d62728", "m": "#1f77b4"}
    bars = ax.barh(
        y,
        typical_mm[order],
        height=0.7,
        color=[family.get(units[k], "#8c8c8c") for k in order],
    )
    for b, k in zip(bars, order, strict=True):
        if not ok[k]:
            b.set_hatch("///")
            b.set_alpha(0.35)
    if identified_mm is not None:
        v = np.asarray(identified_mm, dtype=float)[order]
        sel = ok[order] & (v > 0)
        ax.scatter(v[sel], y[sel], color="black", s=12, zorder=3, label="identified error")
    from matplotlib.patches import Patch

    handles = [
        Patch(color=family["rad"], label="angle, typical error"),
        Patch(color=family["m"], label="length, typical error"),
    ]
    if any(units[k] not in family for k in order):
        handles.append(Patch(color="#8c8c8c", label="other effect, typical error"))
    if identified_mm is not None:
        handles += ax.get_legend_handles_labels()[0]
    ax.legend(handles=handles, loc="lower right")
    ax.set_yticks(y, [names[k] for k in order], fontsize=7)
    ax.set_ylim(-0.7, len(order) - 0.3)
    ax.set_xlabel("RMS tool-point displacement over the poses (mm)")
    ax.grid(axis="y", visible=False)
    return fig


def singular_values_figure(s: np.ndarray, condition_warning: float = 100.0) -> Figure:
    """Singular values of the column-scaled identification Jacobian (identifiable columns), with
    the smallest acceptable value for the condition-number warning."""
    s = np.asarray(s, dtype=float)
    fig = _figure(4.6, 3.0)
    ax = _axes(fig)
    k = np.arange(1, len(s) + 1)
    ax.semilogy(k, s, "o-", color="#1f77b4", ms=3)
    if len(s):
        ax.axhline(
            s[0] / condition_warning,
            color="#d62728",
            ls="--",
            lw=1,
            label=f"s_max / {condition_warning:g}",
        )
        ax.legend(loc="lower left")
    ax.set_xlabel("index")
    ax.set_ylabel("singular value (scaled)")
    ax.set_title("identification Jacobian")
    return fig


def candidates_figure(
    labels: Sequence[str],
    cv_rms_mm: Sequence[float],
    significant: Sequence[bool],
    current_mm: float,
    floor_mm: float | None = None,
) -> Figure:
    """Held-out RMS that adding each candidate effect would leave (best first), against the
    current model's and the noise floor; significant candidates in colour."""
    labels = list(labels)
    fig = _figure(9.0, 1.3 + 0.26 * len(labels))
    ax = _axes(fig)
    y = np.arange(len(labels))[::-1]
    v = np.asarray(cv_rms_mm, dtype=float)
    sig = np.asarray(significant, dtype=bool)
    ax.hlines(y, v, current_mm, color="#cfd6dc", lw=1.0)
    ax.scatter(v[sig], y[sig], color="#d62728", s=28, zorder=3, label="significant, confirmed")
    ax.scatter(v[~sig], y[~sig], color="#9e9e9e", s=22, zorder=3, label="not significant")
    ax.axvline(current_mm, color="#1f77b4", lw=1.2, label=f"current model {current_mm:.4f} mm")
    if floor_mm:
        ax.axvline(floor_mm, color=_FLOOR, ls="--", lw=1.2, label=f"noise floor {floor_mm:.4f} mm")
    ax.set_yticks(y, labels, fontsize=7.5)
    _plain_log(ax)
    ax.set_xlabel("held-out RMS after adding the candidate (mm, log scale)")
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=4)
    ax.grid(axis="y", visible=False)
    return fig
