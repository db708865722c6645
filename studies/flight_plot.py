"""`bof-plot RUN`: draw a flight from its flight.mcap alone, the way Foxglove's standard view shows it.

RUN is a run folder (every flight*.mcap in it) or one .mcap file. For each file, beside it:

    <name>-scene.png   the 3-D scene: the pursuer's, target's and estimate's paths (north, east, up), the
                       estimate's 2-sigma ellipsoid and the bearing ray at a few instants
    <name>-plots.png   over flight time: range, range estimate +- 2 sigma_r, r_d and r_d / 2; the range-estimation
                       error; the IMM model probabilities; tilt; the health monitor's suspect periods shaded and
                       the engagement time marked on every panel

Nothing else of the run folder is read: what the figures show is what the MCAP holds.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (backend first)
import numpy as np  # noqa: E402

from interfaces.cli import CommandParser  # noqa: E402
from interfaces.flight_channels import SCENE_TOPIC, FlightFile, read_flight  # noqa: E402
from studies.plots import set_metric_aspect, suspect_spans  # noqa: E402

#: How many of the scene's ellipsoids and rays the 3-D figure draws (evenly spaced over the flight).
SCENE_SNAPSHOTS = 6


def _engaged_at(flight: FlightFile) -> float | None:
    text = flight.metadata.get("flight", {}).get("engaged_at", "")
    try:
        return float(text) if text else None
    except ValueError:
        return None


def _up(points: np.ndarray) -> np.ndarray:
    """NED (N, 3) -> north, east, up."""
    return np.column_stack([points[:, 0], points[:, 1], -points[:, 2]]) if len(points) else points.reshape(0, 3)


def scene_figure(flight: FlightFile, title: str) -> plt.Figure:
    """The 3-D scene: paths from the pose channels, ellipsoids and rays from /scene."""
    figure = plt.figure(figsize=(15, 7))
    axes = figure.add_subplot(1, 2, 1, projection="3d")
    plan = figure.add_subplot(1, 2, 2)
    drawn = []
    for which, color in (("pursuer", "tab:blue"), ("target", "tab:red"), ("estimate", "tab:orange")):
        _, points = flight.positions(which)
        if len(points):
            points = _up(points)
            axes.plot(points[:, 0], points[:, 1], points[:, 2], color=color, lw=1.2, label=which)
            plan.plot(points[:, 1], points[:, 0], color=color, lw=1.0, label=which)
            drawn.append(points)
    updates = flight.messages.get(SCENE_TOPIC, [])
    with_ellipsoid = [k for k, update in enumerate(updates) if any(e.id == "estimate_ellipsoid" for e in update.entities)]
    picks = [with_ellipsoid[int(i)] for i in np.linspace(0, len(with_ellipsoid) - 1, SCENE_SNAPSHOTS)] if with_ellipsoid else []
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0, np.pi, 12))
    sphere = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], axis=-1)
    for k in picks:
        for entity in updates[k].entities:
            for primitive in entity.spheres:
                q = primitive.pose.orientation
                rotation = _rotation(q.w, q.x, q.y, q.z)
                radii = np.array([primitive.size.x, primitive.size.y, primitive.size.z]) / 2.0
                centre = np.array([primitive.pose.position.x, primitive.pose.position.y, primitive.pose.position.z])
                surface = centre + (sphere * radii) @ rotation.T
                axes.plot_surface(surface[..., 0], surface[..., 1], -surface[..., 2], color="tab:orange", alpha=0.25,
                                  linewidth=0)
                # plan view: the horizontal block of the ellipsoid's matrix R diag(radii^2) R', as an ellipse
                horizontal = (rotation @ np.diag(radii ** 2) @ rotation.T)[:2, :2]
                values, vectors = np.linalg.eigh(horizontal)
                angle = np.linspace(0, 2 * np.pi, 60)
                ring = centre[:2] + (np.stack([np.cos(angle), np.sin(angle)], axis=1) * np.sqrt(np.maximum(values, 0))) @ vectors.T
                plan.fill(ring[:, 1], ring[:, 0], color="tab:orange", alpha=0.25, lw=0)
            if entity.id == "bearing":
                for line in entity.lines:
                    ends = _up(np.array([[p.x, p.y, p.z] for p in line.points]))
                    axes.plot(ends[:, 0], ends[:, 1], ends[:, 2], color="tab:green", lw=0.8)
                    plan.plot(ends[:, 1], ends[:, 0], color="tab:green", lw=0.8)
    if picks:
        axes.plot([], [], color="tab:green", lw=0.8, label=f"bearing ray ({len(picks)} instants)")
    if drawn:
        set_metric_aspect(axes, np.vstack(drawn))
    axes.set_xlabel("north [m]")
    axes.set_ylabel("east [m]")
    axes.set_title(title)
    axes.legend(loc="upper left", fontsize=8)
    plan.set_xlabel("east [m]")
    plan.set_ylabel("north [m]")
    plan.set_aspect("equal", adjustable="datalim")
    plan.grid(True, alpha=0.3)
    plan.set_title("plan view (2-sigma ellipses and bearing rays at the same instants)")
    figure.tight_layout(w_pad=4.0)  # room for the 3-D axes' vertical label beside the plan view
    return figure


def _rotation(w: float, x: float, y: float, z: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat([x, y, z, w]).as_matrix()


def plots_figure(flight: FlightFile, title: str, tilt_limit_deg: float | None = None) -> plt.Figure:
    """Range, range estimate +- 2 sigma_r, r_d, r_d / 2; the range-estimation error; the IMM model probabilities;
    tilt. Suspect periods shaded, the engagement marked, linear axes throughout."""
    figure, axes = plt.subplots(4, 1, figsize=(10, 10), sharex=True)
    t_range, true_range = flight.series("/flight/range", "range")
    t_estimate, estimate = flight.series("/flight/range", "range_estimate")
    t_sigma, sigma = flight.series("/flight/range", "sigma_r")
    _, desired = flight.series("/flight/range", "desired_range")
    if len(true_range):
        axes[0].plot(t_range, true_range, color="k", lw=1.0, label="range (truth)")
    if len(estimate):
        axes[0].plot(t_estimate, estimate, color="tab:orange", lw=1.0, label="range estimate")
        if len(sigma) == len(estimate):
            axes[0].fill_between(t_estimate, estimate - 2 * sigma, estimate + 2 * sigma, color="tab:orange", alpha=0.2,
                                 label="+- 2 sigma_r")
    if len(desired):
        axes[0].axhline(desired[0], color="tab:green", ls="--", lw=0.8, label="r_d")
        axes[0].axhline(desired[0] / 2, color="tab:red", ls=":", lw=0.8, label="r_d / 2")
    axes[0].set_ylim(bottom=0.0)
    axes[0].set_ylabel("range [m]")
    t_error, error = flight.series("/flight/range", "range_estimation_error")
    if len(error):
        axes[1].plot(t_error, error, color="tab:purple", lw=1.0)
    axes[1].axhline(0.0, color="0.5", lw=0.5)
    axes[1].set_ylabel("r_hat - r [m]")
    for field, color in (("straight", "tab:blue"), ("right", "tab:red"), ("left", "tab:green")):
        times, values = flight.series("/estimator/models", field)
        if len(values):
            axes[2].plot(times, values, color=color, lw=1.0, label=field)
    axes[2].set_ylim(-0.05, 1.05)
    axes[2].set_ylabel("IMM model\nprobability")
    t_tilt, tilt = flight.series("/flight/pursuer", "tilt_deg")
    if len(tilt):
        axes[3].plot(t_tilt, tilt, color="tab:blue", lw=0.8)
    if tilt_limit_deg is not None:
        axes[3].axhline(tilt_limit_deg, color="tab:red", ls=":", lw=0.8, label="tilt limit")
    axes[3].set_ylabel("tilt [deg]")
    axes[3].set_xlabel("simulated time of the flight [s]")
    t_health, suspect = flight.series("/health", "suspect")
    spans = suspect_spans(t_health, suspect) if len(suspect) else []
    engaged = _engaged_at(flight)
    for panel in axes:
        for start, end in spans:
            panel.axvspan(start, end, color="tab:red", alpha=0.12, lw=0)
        if engaged is not None:
            panel.axvline(engaged, color="0.3", ls="--", lw=0.8)
        panel.grid(True, alpha=0.3)
        if panel.get_legend_handles_labels()[0]:
            panel.legend(loc="upper right", fontsize=8)
    if spans:
        axes[0].axvspan(math.nan, math.nan, color="tab:red", alpha=0.12, label="monitor: suspect")
        axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(title + ("" if engaged is None else f" (engaged at {engaged:.1f} s, dashed)"))
    figure.tight_layout()
    return figure


def _tilt_limit(flight: FlightFile) -> float | None:
    text = flight.metadata.get("flight", {}).get("max_tilt_limit_deg", "")
    try:
        return float(text) if text else None
    except ValueError:
        return None


def plot_flight(path: Path, out: Path | None = None) -> list[Path]:
    """Both figures of one flight.mcap; returns the PNG paths (written beside the file, or into `out`)."""
    flight = read_flight(path)
    folder = path.parent if out is None else out
    folder.mkdir(parents=True, exist_ok=True)
    meta = flight.metadata.get("flight", {})
    title = f"{meta.get('scenario', path.stem).strip(chr(34))} ({path.name})"
    written = []
    for suffix, figure in (("scene", scene_figure(flight, title)), ("plots", plots_figure(flight, title, _tilt_limit(flight)))):
        target = folder / f"{path.stem}-{suffix}.png"
        figure.savefig(target, dpi=110)
        plt.close(figure)
        written.append(target)
    return written


def build_parser() -> argparse.ArgumentParser:
    parser = CommandParser(prog="bof-plot", description="Draw a flight's 3-D scene and time plots from its "
                           "flight.mcap alone (a run folder: every flight*.mcap in it).")
    parser.add_argument("run", type=Path, help="a run folder of bof-sim or bof-sitl, or one .mcap file")
    parser.add_argument("--out", type=Path, default=None, help="folder for the PNGs (default: beside each .mcap)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    run: Path = args.run
    if run.is_dir():
        files = sorted(run.glob("flight*.mcap"))
        if not files:
            parser.error(f"{run} holds no flight*.mcap (bof-sim and bof-sitl write flight.mcap in each run folder)")
    elif run.is_file():
        files = [run]
    else:
        parser.error(f"{run}: no such file or folder")
    status = 0
    for path in files:
        try:
            for written in plot_flight(path, args.out):
                print(written)
        except ValueError as error:
            print(f"bof-plot: {error}", file=sys.stderr)
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())
