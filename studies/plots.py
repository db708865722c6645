"""Plots of one flight, in the style of the paper's Fig. 8: 3-D trajectories and error curves."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (backend must be chosen first)
import numpy as np  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402


def _north_east_up(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return positions[:, 0], positions[:, 1], -positions[:, 2]


#: The up axis is drawn at least this fraction of the longer horizontal side, so a weave of a few
#: metres stays visible on a 200 m track; when that stretches it, the axis label says by how much.
MIN_VERTICAL_SHARE = 0.25


def vertical_exaggeration(spans: tuple[float, float, float]) -> float:
    """How much the up axis of a 3-D trajectory is stretched against north/east (1 = equal aspect).

    spans: extents (north, east, up) of the plotted data, m. Returns k >= 1 such that the up side
    of the box is k * spans[2], i.e. at least MIN_VERTICAL_SHARE of the longer horizontal side.
    """
    horizontal = max(spans[0], spans[1])
    if spans[2] <= 0.0 or spans[2] >= MIN_VERTICAL_SHARE * horizontal:
        return 1.0
    return MIN_VERTICAL_SHARE * horizontal / spans[2]


def set_metric_aspect(axes, points: np.ndarray, up_label: str = "up [m]") -> None:
    """On 3-D `axes`, given the plotted points (N, 3) (north, east, up; m): equal metres on north and
    east, and on up unless a flat flight needs stretching, which the up label then says."""
    points = points[np.all(np.isfinite(points), axis=1)]
    spans = tuple(float(max(np.ptp(points[:, axis]), 1e-3)) for axis in range(3)) if len(points) else (1.0, 1.0, 1.0)
    stretch = vertical_exaggeration(spans)
    axes.set_box_aspect((spans[0], spans[1], spans[2] * stretch))
    axes.zaxis.set_major_locator(MaxNLocator(4))
    axes.set_zlabel(up_label if stretch == 1.0 else f"{up_label}, stretched x{stretch:.2g}")


def plot_trajectories(series: dict[str, np.ndarray], path: Path, title: str) -> None:
    """Fig. 8(a): target, estimated target and pursuer in 3-D (north, east, up), stars at the start.

    North and east share one scale; up too, unless the flight is so flat that its weave would be
    invisible: the up axis is then stretched and its label says by how much."""
    figure = plt.figure(figsize=(7.5, 6.0))
    axes = figure.add_subplot(projection="3d")
    drawn = []
    for key, label, style in (
        ("target_position", "target", "r-"),
        ("estimate_position", "estimated target", "g--"),
        ("pursuer_position", "pursuer", "b-"),
    ):
        north, east, up = _north_east_up(series[key])
        finite = np.isfinite(north)
        axes.plot(north[finite], east[finite], up[finite], style, label=label, linewidth=1.2)
        drawn.append(np.column_stack([north[finite], east[finite], up[finite]]))
        if finite.any():
            first = np.argmax(finite)
            axes.scatter([north[first]], [east[first]], [up[first]], marker="*", s=80, color=style[0])
    axes.set_xlabel("north [m]")
    axes.set_ylabel("east [m]")
    set_metric_aspect(axes, np.concatenate(drawn))
    axes.set_title(title)
    axes.legend(loc="upper left")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


def suspect_spans(times: np.ndarray, suspect: np.ndarray) -> list[tuple[float, float]]:
    """The (start, end) times of each run of suspect samples (a run ends at the next sample that is not)."""
    spans, start = [], None
    for k, flagged in enumerate(suspect > 0.5):
        if flagged and start is None:
            start = times[k]
        elif not flagged and start is not None:
            spans.append((float(start), float(times[k])))
            start = None
    if start is not None:
        spans.append((float(start), float(times[-1])))
    return spans


def plot_errors(series: dict[str, np.ndarray], desired_range: float, path: Path, title: str,
                summary: dict | None = None) -> None:
    """errors_figure saved to `path` (PNG)."""
    figure = errors_figure(series, desired_range, title, summary)
    figure.savefig(path, dpi=120)
    plt.close(figure)


def errors_figure(series: dict[str, np.ndarray], desired_range: float, title: str,
                  summary: dict | None = None) -> plt.Figure:
    """Fig. 8(b): position, velocity and range estimation errors, and the range against r_d.

    The two error norms (>= 0) are on a log axis; the signed range-estimation error, which crosses zero, and
    the range on linear axes. With the flight's `summary` (studies.metrics.summarize) every panel marks the
    summary window (shaded, its last summary_window seconds) and the convergence time (dashed); spans the
    health monitor called suspect (series "health_suspect") are shaded red."""
    time = series["time"]
    position_error = np.linalg.norm(series["estimate_position"] - series["target_position"], axis=1)
    velocity_error = np.linalg.norm(series["estimate_velocity"] - series["target_velocity"], axis=1)
    range_estimation_error = series["range_estimate"] - series["range"]
    figure, axes = plt.subplots(4, 1, figsize=(8.0, 9.0), sharex=True)
    axes[0].plot(time, position_error, "k-", linewidth=1.0)
    axes[0].set_ylabel("|p^_T - p_T| [m]")
    axes[1].plot(time, velocity_error, "k-", linewidth=1.0)
    axes[1].set_ylabel("|v^_T - v_T| [m/s]")
    axes[2].plot(time, range_estimation_error, "k-", linewidth=1.0)
    axes[2].axhline(0.0, color="grey", linewidth=0.6)
    axes[2].set_ylabel("r^ - r [m]")
    axes[3].plot(time, series["range"], "b-", linewidth=1.0, label="range r")
    axes[3].plot(time, series["range_estimate"], "g--", linewidth=1.0, label="estimated range")
    axes[3].axhline(desired_range, color="r", linestyle=":", label="desired r_d")
    axes[3].axhline(0.5 * desired_range, color="darkred", linestyle=":", linewidth=0.8, label="r_d / 2")
    axes[3].set_ylabel("range [m]")
    axes[3].set_xlabel("time [s]")
    for ax in axes[:2]:
        ax.set_yscale("log")
    suspect = series.get("health_suspect")
    spans = suspect_spans(time, np.asarray(suspect, dtype=float).reshape(-1)) if suspect is not None else []
    window = summary.get("summary_window") if summary else None
    convergence = summary.get("convergence_time") if summary else None
    for k, ax in enumerate(axes):
        for start, end in spans:
            ax.axvspan(start, end, color="tab:red", alpha=0.12, linewidth=0, label="suspect" if k == 3 and start == spans[0][0] else None)
        if window and len(time):
            ax.axvspan(max(float(time[-1]) - window, float(time[0])), float(time[-1]), color="grey", alpha=0.12,
                       linewidth=0, label=f"summary window (last {window:g} s)" if k == 3 else None)
        if convergence is not None and math.isfinite(convergence):
            ax.axvline(convergence, color="tab:green", linestyle="--", linewidth=0.9,
                       label=f"converged at {convergence:.1f} s" if k == 3 else None)
        ax.grid(True, which="major", alpha=0.3)
    axes[3].legend(loc="upper right", fontsize="small")
    axes[0].set_title(title)
    figure.tight_layout()
    return figure


def plot_observability_comparison(flights: dict[str, dict[str, np.ndarray]], path: Path, title: str) -> None:
    """The windowed FIM measure (section V, eq. (7)) over time for several flights, e.g. HNG against PPG:
    log10 det and the smallest eigenvalue of the FIM of the bearings used in the last window."""
    figure, axes = plt.subplots(2, 1, figsize=(8.0, 6.0), sharex=True)
    for label, series in flights.items():
        time = series["time"]
        axes[0].plot(time, series["observability_log_det"], linewidth=1.0, label=label)
        axes[1].plot(time, series["observability_min_eigenvalue"], linewidth=1.0, label=label)
    axes[0].set_ylabel("log10 det(FIM)")
    axes[1].set_ylabel("smallest eigenvalue of FIM")
    axes[1].set_yscale("log")
    axes[1].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right")
    axes[0].set_title(title)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


def plot_swarm_tracks(series: dict[int, dict[str, np.ndarray]], path: Path, title: str) -> None:
    """Several pursuers around one target: the target (red), each pursuer's track and its estimate of the
    target (dashed, same colour), in 3-D (north, east, up) and from above; stars at the start."""
    figure = plt.figure(figsize=(13.0, 6.0))
    axes3d = figure.add_subplot(1, 2, 1, projection="3d")
    above = figure.add_subplot(1, 2, 2)
    first = next(iter(series.values()))
    points = [np.column_stack(_north_east_up(first["target_position"]))]
    north, east, up = _north_east_up(first["target_position"])
    axes3d.plot(north, east, up, "r-", label="target")
    above.plot(east, north, "r-", label="target")
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for index, (ident, data) in enumerate(sorted(series.items())):
        colour = colours[index % len(colours)]
        north, east, up = _north_east_up(data["pursuer_position"])
        points.append(np.column_stack((north, east, up)))
        axes3d.plot(north, east, up, "-", color=colour, lw=1.0, label=f"pursuer {ident}")
        axes3d.scatter([north[0]], [east[0]], [up[0]], marker="*", color=colour, s=60)
        above.plot(east, north, "-", color=colour, lw=1.0, label=f"pursuer {ident}")
        above.plot([east[0]], [north[0]], "*", color=colour, ms=10)
        estimate = data["estimate_position"]
        if np.isfinite(estimate).any():
            e_north, e_east, _ = _north_east_up(estimate)
            above.plot(e_east, e_north, "--", color=colour, lw=0.7, label=f"estimate {ident}")
    set_metric_aspect(axes3d, np.vstack(points))
    axes3d.set_xlabel("north [m]")
    axes3d.set_ylabel("east [m]")
    axes3d.legend(loc="upper left", fontsize=7)
    above.set_xlabel("east [m]")
    above.set_ylabel("north [m]")
    above.set_aspect("equal", adjustable="datalim")
    above.legend(loc="best", fontsize=7)
    above.set_title("from above")
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
