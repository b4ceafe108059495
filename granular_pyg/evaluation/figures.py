"""Figures in the paper's style: ground truth solid, prediction dashed."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from granular_pyg.errors import InputError
from granular_pyg.evaluation.pair import PairEvaluation

__all__ = ["comparison_figure", "discharge_figure", "variants_figure"]

TRUTH = {"ls": "-", "lw": 1.6}
PRED = {"ls": "--", "lw": 1.6}
AXES = ("x", "y", "z")
COLOURS = ("tab:blue", "tab:orange", "tab:green")


def comparison_figure(ev: PairEvaluation, title: str = ""):
    """Six panels of one rollout against its ground truth (solid: LIGGGHTS, dashed: learned):
    particle-averaged position, flow profile over z, flow over time, mixing entropy, the
    scene's observable (hopper: discharged fraction; drum: dynamic angle of repose; other: the
    fraction of particles that left) and EMD against the learned step (log-log). A panel the
    scene cannot have (mixing in a scene of kind ``other``) says so.

    Args:
        ev: the evaluation of one (truth, prediction) pair.
        title: figure title.

    Returns:
        A matplotlib ``Figure`` (no pyplot state: the caller saves, logs or displays it).
    """
    s = ev.series
    t = s["times"]
    fig = Figure(figsize=(13, 7))
    axes = fig.subplots(2, 3)
    ax = axes[0, 0]
    for i, (name, colour) in enumerate(zip(AXES, COLOURS, strict=True)):
        ax.plot(t, s["mean_pos_truth"][:, i], color=colour, label=name, **TRUTH)
        ax.plot(t, s["mean_pos_pred"][:, i], color=colour, **PRED)
    _labels(ax, "time (s)", "particle-averaged position (m)", "Averaged position")
    ax.legend(fontsize=8)

    ax = axes[0, 1]
    ax.plot(s["flow_z_truth"], s["flow_z_centres"], color="k", **TRUTH, label="LIGGGHTS")
    ax.plot(s["flow_z_pred"], s["flow_z_centres"], color="tab:red", **PRED, label="learned")
    _labels(ax, "mean v_z (m/s)", "z (m)", "Flow profile over z")
    ax.legend(fontsize=8)

    ax = axes[0, 2]
    ax.plot(t, s["flow_t_truth"], color="k", **TRUTH)
    ax.plot(t, s["flow_t_pred"], color="tab:red", **PRED)
    _labels(ax, "time (s)", "mean v_z (m/s)", "Flow over time")

    ax = axes[1, 0]
    ax.plot(t, s["entropy_truth"], color="k", **TRUTH)
    ax.plot(t, s["entropy_pred"], color="tab:red", **PRED)
    ax.axhline(np.log(2), color="0.6", lw=0.8)
    _labels(ax, "time (s)", "mixing entropy", f"Mixing (split at t = {t[ev.mixing_frame]:.3g} s)")
    _note_if_undefined(ax, s["entropy_truth"], "no mixing axis for this scene")

    ax = axes[1, 1]
    key, label = ev.observable
    ax.plot(t, s[f"{key}_truth"], color="k", **TRUTH)
    ax.plot(t, s[f"{key}_pred"], color="tab:red", **PRED)
    _labels(ax, "time (s)", label, label.split(" (")[0].capitalize())
    _note_if_undefined(ax, s[f"{key}_truth"], "not defined for this scene")

    ax = axes[1, 2]
    steps = np.array(sorted(ev.emd_steps))
    if len(steps):
        ax.loglog(steps, [ev.emd_steps[k] for k in steps], "o-", color="tab:red")
    _labels(ax, "learned step", "EMD W2^2 (m^2)", "EMD at steps 2^k")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


#: Colours of the variants in :func:`variants_figure`.
VARIANT_COLOURS = {"V1": "tab:blue", "V2": "tab:orange", "V3": "tab:red"}


def variants_figure(evaluations: dict[str, PairEvaluation], title: str = ""):
    """The paper's Figure 2: one ground truth (solid black) against each variant's rollout
    (dashed): particle-averaged height, flow profile over z, mixing entropy and the scene's
    observable (hopper: discharged fraction; drum: dynamic angle of repose; other: the fraction
    of particles that left).

    Args:
        evaluations: ``{variant name: evaluation}`` of rollouts of the same trajectory.
        title: figure title.

    Returns:
        A matplotlib ``Figure`` with four panels (no pyplot state).

    Raises:
        InputError: ``evaluations`` is empty.
    """
    if not evaluations:
        raise InputError("evaluations: give at least one variant's evaluation")
    first = next(iter(evaluations.values()))
    fig = Figure(figsize=(16, 4))
    axes = fig.subplots(1, 4)
    key, label = first.observable
    panels = [
        ("times", "mean_pos_{}", "time (s)", "particle-averaged z (m)", "Averaged position"),
        ("flow_z", "flow_z_{}", "mean v_z (m/s)", "z (m)", "Flow profile over z"),
        ("times", "entropy_{}", "time (s)", "mixing entropy", "Mixing entropy"),
        ("times", f"{key}_{{}}", "time (s)", label, label.split(" (")[0].capitalize()),
    ]
    curves = [("truth", first, {"color": "k", "label": "LIGGGHTS", **TRUTH})] + [
        ("pred", ev, {"color": VARIANT_COLOURS.get(name), "label": name, **PRED})
        for name, ev in evaluations.items()
    ]
    for ax, (x_key, y_key, xlabel, ylabel, name) in zip(axes, panels, strict=True):
        for who, ev, style in curves:
            y = ev.series[y_key.format(who)]
            y = y[:, 2] if y.ndim == 2 else y
            if x_key == "flow_z":
                ax.plot(y, ev.series["flow_z_centres"], **style)
            else:
                ax.plot(ev.series["times"], y, **style)
        _labels(ax, xlabel, ylabel, name)
    axes[0].legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def discharge_figure(ev: PairEvaluation, title: str = ""):
    """The discharge curve of a hopper: mass of the initial bed that has left (kg) against
    time (s), LIGGGHTS solid, learned dashed, with the bed's mass and, where the scene's outlet
    allows it, Beverloo's rate as a straight reference line of that slope through the point
    where LIGGGHTS's curve passes 20% of the bed (its fit window's start); the fitted windows
    of both rates are marked.

    Args:
        ev: the evaluation of one hopper (truth, prediction) pair (``series`` has
            ``discharged_mass_*``, ``bed_mass``, ``rate_window_*``; ``scalars``
            ``beverloo_rate``).
        title: figure title.

    Returns:
        A matplotlib ``Figure`` (no pyplot state).

    Raises:
        InputError: an evaluation without discharge curves (not a hopper).
    """
    s = ev.series
    if "discharged_mass_truth" not in s:
        raise InputError("ev: has no discharge curve; only a hopper's evaluation has one")
    t = s["times"]
    bed = float(s["bed_mass"])
    fig = Figure(figsize=(6.5, 4.2))
    ax = fig.subplots()
    ax.plot(t, s["discharged_mass_truth"], color="k", label="LIGGGHTS", **TRUTH)
    ax.plot(t, s["discharged_mass_pred"], color="tab:red", label="learned", **PRED)
    ax.axhline(bed, color="0.6", lw=0.8, label=f"initial bed {bed * 1e3:.4g} g")
    for who, colour in (("truth", "k"), ("pred", "tab:red")):
        lo, hi = s[f"rate_window_{who}"]
        rate = ev.scalars.get(f"discharge_rate_{who}", float("nan"))
        if np.isfinite(lo) and np.isfinite(rate):
            ax.axvspan(lo, hi, color=colour, alpha=0.06)
    beverloo = ev.scalars.get("beverloo_rate", float("nan"))
    start = s["rate_window_truth"][0]
    if np.isfinite(beverloo) and beverloo > 0 and np.isfinite(start):
        m0 = float(np.interp(start, t, s["discharged_mass_truth"]))
        t1 = start + (bed - m0) / beverloo
        ax.plot(
            [start, t1],
            [m0, bed],
            color="tab:blue",
            lw=1.0,
            ls=":",
            label=f"Beverloo {beverloo:.3g} kg/s",
        )
    truth_rate = ev.scalars.get("discharge_rate_truth", float("nan"))
    pred_rate = ev.scalars.get("discharge_rate_pred", float("nan"))
    ax.text(
        0.02,
        0.97,
        f"rate: LIGGGHTS {truth_rate:.3g}, learned {pred_rate:.3g} kg/s\n"
        f"gone at the end: {ev.scalars.get('discharged_fraction_truth', np.nan):.1%} / "
        f"{ev.scalars.get('discharged_fraction_pred', np.nan):.1%} of the bed",
        transform=ax.transAxes,
        va="top",
        fontsize=8,
    )
    ax.set_ylim(0, 1.08 * bed if bed > 0 else 1.0)
    _labels(ax, "time (s)", "discharged mass of the initial bed (kg)", "Discharge")
    ax.legend(fontsize=8, loc="lower right")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def _note_if_undefined(ax, curve: np.ndarray, why: str) -> None:
    """Say so on a panel whose curve the scene cannot have (all NaN)."""
    if not np.isfinite(curve).any():
        ax.text(0.5, 0.5, why, ha="center", va="center", transform=ax.transAxes, color="0.4")


def _labels(ax, xlabel: str, ylabel: str, title: str) -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
