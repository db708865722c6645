"""Figures of a bof-montecarlo run (the paper's Figs. 10-14 in form).

* errors_over_time.png: mean (solid) and median (dashed) |range-estimation error| over the
  runs against time, one curve per estimator / guidance law / case (Fig. 10, Fig. 13),
  one panel per remaining combination.
* trajectories.png: pursuer and target of the first seed of every group (Figs. 11-12).
* image_plane.png: the target in the normalised image plane of the first seed of every
  group (Fig. 14); the star marks the start.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from studies.plots import set_metric_aspect  # noqa: E402

DIMENSIONS = ("scenario", "estimator", "guidance", "case")
MAX_PANELS = 16
#: Font sizes (pt) readable at the saved size on a laptop screen or a printed page.
FONTS = {"font.size": 11, "axes.titlesize": 11, "axes.labelsize": 11, "xtick.labelsize": 10, "ytick.labelsize": 10,
         "legend.fontsize": 10, "figure.titlesize": 13}


def choose_curves_by(rows: list[dict]) -> str:
    """The dimension with the most distinct values (estimator first on ties)."""
    counts = {dim: len({row[dim] for row in rows}) for dim in ("estimator", "guidance", "case")}
    return max(counts, key=lambda dim: (counts[dim], -("estimator", "guidance", "case").index(dim)))


def _label(row: dict, dims: tuple[str, ...]) -> str:
    return " / ".join(str(row[dim]) for dim in dims)


def _common(rows: list[dict], dims: tuple[str, ...]) -> str:
    """'scenario constant_velocity, guidance hng' for the dims of `dims` that one value fills in every row."""
    return ", ".join(f"{dim} {rows[0][dim]}" for dim in dims if len({row[dim] for row in rows}) == 1)


def _grid(count: int) -> tuple[int, int]:
    columns = min(count, 4)
    return math.ceil(count / columns), columns


@plt.rc_context(FONTS)
def errors_over_time(rows: list[dict], series: dict[str, np.ndarray], path: Path, curves_by: str, title: str) -> None:
    """One panel per combination of the dimensions other than `curves_by` that vary; its title names
    that combination, or (a single panel) what all runs share."""
    facets_dims = tuple(dim for dim in DIMENSIONS if dim != curves_by and len({row[dim] for row in rows}) > 1)
    facets = list(dict.fromkeys(_label(row, facets_dims) for row in rows))[:MAX_PANELS]
    curves = list(dict.fromkeys(row[curves_by] for row in rows))
    n_rows, n_cols = _grid(len(facets))
    figure, axes = plt.subplots(n_rows, n_cols, figsize=(6.0 * n_cols, 4.4 * n_rows), squeeze=False, sharey=True)
    time = series["time"][0]
    error = np.abs(series["range_estimation_error"])
    for panel, facet in enumerate(facets):
        axis = axes.flat[panel]
        for colour, curve in enumerate(curves):
            chosen = [i for i, row in enumerate(rows) if row[curves_by] == curve and _label(row, facets_dims) == facet]
            if not chosen:
                continue
            with warnings.catch_warnings():  # columns before engagement are all NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                mean = np.nanmean(error[chosen], axis=0)
                median = np.nanmedian(error[chosen], axis=0)
            diverged = sum(rows[i]["diverged"] for i in chosen)
            axis.semilogy(time, mean, color=f"C{colour}", label=f"{curve} ({diverged}/{len(chosen)} diverged)")
            axis.semilogy(time, median, color=f"C{colour}", linestyle="--", linewidth=0.8)
        shared = _common(rows, tuple(dim for dim in DIMENSIONS if dim != curves_by))
        axis.set_title(facet or f"one curve per {curves_by}" + (f"\n{shared}" if shared else ""))
        axis.set_xlabel("time (s)")
        axis.set_ylim(1e-3, 1e3)
        axis.grid(True, which="both", alpha=0.3)
        axis.legend()
    for axis in axes.flat[len(facets):]:
        axis.set_visible(False)
    axes[0, 0].set_ylabel("|range-estimation error| (m)\nmean solid, median dashed")
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _first_seed_per_group(rows: list[dict]) -> list[int]:
    seen: dict[tuple, int] = {}
    for index, row in enumerate(rows):
        key = tuple(row[dim] for dim in DIMENSIONS)
        if key not in seen or row["seed"] < rows[seen[key]]["seed"]:
            seen[key] = index
    return list(seen.values())[:MAX_PANELS]


@plt.rc_context(FONTS)
def trajectories(rows: list[dict], series: dict[str, np.ndarray], path: Path, title: str) -> None:
    chosen = _first_seed_per_group(rows)
    dims = tuple(dim for dim in DIMENSIONS if len({row[dim] for row in rows}) > 1) or ("scenario",)
    n_rows, n_cols = _grid(len(chosen))
    figure = plt.figure(figsize=(5.4 * n_cols, 5.0 * n_rows))
    for panel, index in enumerate(chosen):
        axis = figure.add_subplot(n_rows, n_cols, panel + 1, projection="3d")
        pursuer, target = series["pursuer_position"][index], series["target_position"][index]
        # NED -> north, east, up for the eye
        axis.plot(target[:, 0], target[:, 1], -target[:, 2], color="C3", label="target")
        axis.plot(pursuer[:, 0], pursuer[:, 1], -pursuer[:, 2], color="C0", label="pursuer")
        axis.scatter([target[0, 0], pursuer[0, 0]], [target[0, 1], pursuer[0, 1]], [-target[0, 2], -pursuer[0, 2]],
                     marker="*", s=80, color="k")
        row = rows[index]
        axis.set_title(f"{_label(row, dims)}, seed {row['seed']}" + (" (lost)" if row["lost"] else ""))
        axis.set_xlabel("north (m)")
        axis.set_ylabel("east (m)")
        set_metric_aspect(axis, np.concatenate([np.column_stack([p[:, 0], p[:, 1], -p[:, 2]]) for p in (pursuer, target)]),
                          "up (m)")
        if panel == 0:
            axis.legend()
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


@plt.rc_context(FONTS)
def image_plane(rows: list[dict], series: dict[str, np.ndarray], path: Path, title: str) -> None:
    chosen = _first_seed_per_group(rows)
    dims = tuple(dim for dim in DIMENSIONS if len({row[dim] for row in rows}) > 1) or ("scenario",)
    n_rows, n_cols = _grid(len(chosen))
    figure, axes = plt.subplots(n_rows, n_cols, figsize=(4.6 * n_cols, 4.6 * n_rows), squeeze=False)
    for panel, index in enumerate(chosen):
        axis = axes.flat[panel]
        points = series["image_plane"][index]
        finite = np.all(np.isfinite(points), axis=1)
        axis.plot(points[finite, 0], points[finite, 1], linewidth=0.7)
        if finite.any():
            first = points[np.argmax(finite)]
            axis.plot(first[0], first[1], marker="*", markersize=10, color="k")
        axis.set_xlim(-1.0, 1.0)
        axis.set_ylim(1.0, -1.0)  # image y (down) grows downwards
        axis.set_aspect("equal")
        axis.set_xticks([-1.0, -0.5, 0.0, 0.5, 1.0])
        axis.set_yticks([-1.0, -0.5, 0.0, 0.5, 1.0])
        axis.grid(True, alpha=0.3)
        axis.set_title(f"{_label(rows[index], dims)}, seed {rows[index]['seed']}")
        axis.set_xlabel("x_n (right)")
        axis.set_ylabel("y_n (down)")
    for axis in axes.flat[len(chosen):]:
        axis.set_visible(False)
    figure.suptitle(title + "\nnormalised image plane of a level camera with the vehicle's position and yaw")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def draw_all(rows: list[dict], series: dict[str, np.ndarray], folder: Path, curves_by: str | None, title: str) -> str:
    """Draw the three figures into `folder`; return Markdown that links them."""
    curves_by = curves_by or choose_curves_by(rows)
    errors_over_time(rows, series, folder / "errors_over_time.png", curves_by, title)
    trajectories(rows, series, folder / "trajectories.png", title)
    image_plane(rows, series, folder / "image_plane.png", title)
    return ("\n![range-estimation error over time](errors_over_time.png)\n\n![trajectories](trajectories.png)\n\n"
            "![image plane](image_plane.png)\n")
