"""Figures 3-5 of section V: the eq. (12) placement optimiser and its Monte Carlo comparison.

Writes fig3.png (convergence snapshots), fig4.png (stronger plane; plus top/bottom planes),
fig5.png (||G||_F of the optimised placement against random placements) and summary.json
into a new run folder observability-<time>/ inside --out (default runs/), like every bof-*
command. sigma = r_d = 1 and n = 10 throughout.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (backend must be chosen first)
import numpy as np  # noqa: E402

from interfaces.run_folders import new_run_folder
from interfaces.scenario import DEFAULT_SCENARIO  # noqa: E402
from interfaces.cli import CommandParser, output_folder
from studies.metrics import write_summary  # noqa: E402
from companion.core.observability import (  # noqa: E402
    Plane,
    PlacementResult,
    g_matrix,
    optimize_placement,
    random_placement,
)

PARTICLES = 10
K_G = 1.0
K_M = 5.0
DT = 1e-3
SNAPSHOT_TIMES = (0.0, 1.0, 2.0, 10.0)
PAPER_G_NORM = 5.93
BACK_PLANE = dict(point=[-1.0, 0.0, 0.0], normal=[1.0, 0.0, 0.0])  # allowed side x > -1
TOP_PLANE = Plane(point=[0.0, 0.0, 1.0], normal=[0.0, 0.0, -1.0], gain=2.0)
BOTTOM_PLANE = Plane(point=[0.0, 0.0, -1.0], normal=[0.0, 0.0, 1.0], gain=2.0)


def _draw_planes(axes, planes: list[Plane]) -> None:
    """Each repulsive plane of eq. (12c) as a translucent square of side 2 (the sphere's box) around
    its point, with a short arrow along its normal into the allowed side (as in the paper's Fig. 3)."""
    for plane in planes:
        # Two unit vectors spanning the plane: Gram-Schmidt on the axis least aligned with the normal.
        seed = np.eye(3)[int(np.argmin(np.abs(plane.normal)))]
        first = seed - (seed @ plane.normal) * plane.normal
        first /= np.linalg.norm(first)
        second = np.cross(plane.normal, first)
        s, t = np.meshgrid([-1.0, 1.0], [-1.0, 1.0])
        corners = plane.point + s[..., None] * first + t[..., None] * second
        axes.plot_surface(corners[..., 0], corners[..., 1], corners[..., 2], color="tab:orange", alpha=0.25,
                          edgecolor="tab:orange", linewidth=0.8, shade=False)
        axes.quiver(*plane.point, *(0.4 * plane.normal), color="tab:orange", linewidth=1.2)


def _draw_particles(axes, positions: np.ndarray, velocities: np.ndarray, title: str,
                    planes: list[Plane] = ()) -> None:
    _draw_planes(axes, list(planes))
    u, v = np.mgrid[0 : 2 * np.pi : 30j, 0 : np.pi : 15j]
    axes.plot_wireframe(np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v), color="0.85", linewidth=0.4)
    axes.scatter(*positions.T, color="tab:blue", s=25, depthshade=False)
    axes.quiver(*positions.T, *(0.2 * velocities).T, color="tab:red", linewidth=1.0)
    axes.set_xlim(-1, 1)
    axes.set_ylim(-1, 1)
    axes.set_zlim(-1, 1)
    axes.set_box_aspect((1, 1, 1))
    for set_ticks in (axes.set_xticks, axes.set_yticks, axes.set_zticks):
        set_ticks([-1.0, 0.0, 1.0])
    axes.set_xlabel("x")
    axes.set_ylabel("y")
    axes.set_zlabel("z")
    axes.set_title(title, fontsize=9)


def _g_norm(bearings: np.ndarray) -> float:
    return float(np.linalg.norm(g_matrix(bearings, np.ones(len(bearings)), 1.0)))


def figure3(initial: np.ndarray, path: Path) -> PlacementResult:
    """Fig. 3: one plane through [-1,0,0], k_g = k_b = 1, k_m = 5; snapshots at 0, 1, 2, 10 s.

    The plane is drawn (orange, arrow into the allowed side x > -1)."""
    planes = [Plane(gain=1.0, **BACK_PLANE)]
    result = optimize_placement(
        initial, planes, k_g=K_G, k_m=K_M, dt=DT, duration=max(SNAPSHOT_TIMES), record_times=SNAPSHOT_TIMES
    )
    figure = plt.figure(figsize=(12.0, 3.6))
    for index, (when, positions, velocities) in enumerate(zip(result.times, result.positions, result.velocities)):
        axes = figure.add_subplot(1, 4, index + 1, projection="3d")
        title = f"({'abcd'[index]}) t = {when:g} s, ||G||_F = {_g_norm(positions):.3f}"
        _draw_particles(axes, positions, velocities, title, planes)
    figure.suptitle("particles (blue) and velocities (red) on the unit sphere; repulsive plane x = -1 (orange)",
                    fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return result


def figure4(initial: np.ndarray, path: Path) -> tuple[PlacementResult, PlacementResult]:
    """Fig. 4: (a) back plane with k_b = 10; (b) plus top and bottom planes with k_b = 2."""
    strong_back = Plane(gain=10.0, **BACK_PLANE)
    cases = ([strong_back], [strong_back, TOP_PLANE, BOTTOM_PLANE])
    duration = max(SNAPSHOT_TIMES)
    results = tuple(
        optimize_placement(initial, planes, k_g=K_G, k_m=K_M, dt=DT, duration=duration, record_times=[duration])
        for planes in cases
    )
    figure = plt.figure(figsize=(8.0, 4.0))
    labels = ("(a) k_b = 10", "(b) + top/bottom planes, k_b = 2")
    for index, (label, result, planes) in enumerate(zip(labels, results, cases)):
        axes = figure.add_subplot(1, 2, index + 1, projection="3d")
        title = f"{label}, ||G||_F = {result.final_g_norm:.3f}"
        _draw_particles(axes, result.positions[-1], result.velocities[-1], title, planes)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return results


def figure5(optimised_g_norm: float, random_g_norms: np.ndarray, path: Path) -> None:
    """Fig. 5: ||G||_F of random constrained placements, with the optimised value as a red line."""
    figure, axes = plt.subplots(figsize=(7.0, 4.0))
    axes.plot(np.arange(1, len(random_g_norms) + 1), random_g_norms, "k.", markersize=3, label="random placements")
    axes.axhline(optimised_g_norm, color="r", label=f"optimised (Fig. 3(d)) = {optimised_g_norm:.3f}")
    axes.axhline(PARTICLES / math.sqrt(3.0), color="0.5", linestyle="--", label="isotropic bound n/sqrt(3)")
    axes.axhline(PARTICLES / math.sqrt(2.0), color="0.5", linestyle=":", label="great circle n/sqrt(2)")
    axes.set_xlabel("example")
    axes.set_ylabel("||G||_F")
    axes.legend(loc="upper right", fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


DEFAULT_FLIGHT = DEFAULT_SCENARIO


def guidance_comparison(config: Path, path: Path) -> dict:
    """One in-process flight under HNG and one under PPG; the pipeline's windowed FIM (5 s) over time."""
    from interfaces.scenario import load_scenario
    from studies.closed_loop import simulate
    from studies.plots import plot_observability_comparison

    scenario, vehicle = load_scenario(config)
    flights, figures = {}, {}
    for law in ("hng", "ppg"):
        flown = scenario.model_copy(update={"guidance": scenario.guidance.model_copy(update={"law": law})})
        result = simulate(flown, vehicle)
        flights[law.upper()] = result.series
        following = result.series["time"] > 20.0
        figures[law] = {
            "log_det_median": result.summary["observability_log_det_median"],
            "min_eigenvalue_median_after_20s": float(np.nanmedian(result.series["observability_min_eigenvalue"][following])),
            "range_estimation_error_rms": result.summary["range_estimation_error_rms"],
        }
    plot_observability_comparison(flights, path, f"{scenario.name}: windowed FIM of the bearings used (5 s)")
    return figures


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `bof-observability` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="bof-observability", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=output_folder, default=Path("runs"),
                        help="parent folder: the run folder observability-<time>/ is created inside it "
                             "(default: %(default)s)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the initial and random placements (default: %(default)s)")
    parser.add_argument("--random", type=int, default=1000, help="number of random placements in Fig. 5 (default: %(default)s)")
    parser.add_argument("--flight", type=Path, nargs="?", const=DEFAULT_FLIGHT, default=None,
                        help="also fly this scenario (without a value: constant_velocity) in process with HNG and with "
                             "PPG and plot the live, windowed FIM of the bearings used (fig_flight_observability.png); "
                             "default: no flight")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.flight is not None and not args.flight.is_file():
        parser.error(f"--flight {args.flight}: {'is a folder' if args.flight.is_dir() else 'no such file'}; give a scenario file")
    if args.seed < 0:
        parser.error(f"--seed {args.seed} is negative (seeds are integers >= 0)")
    if args.random < 1:
        parser.error("--random must be at least 1")
    if args.flight is not None:  # check the scenario before any figure or folder is made
        from interfaces.scenario import ConfigError, load_scenario

        try:
            load_scenario(args.flight)
        except ConfigError as error:
            parser.error(f"--flight: {error}")
    out = new_run_folder(args.out, "observability")

    rng = np.random.default_rng(args.seed)
    back_plane = [Plane(gain=1.0, **BACK_PLANE)]
    initial = random_placement(PARTICLES, rng, back_plane)
    fig3 = figure3(initial, out / "fig3.png")
    fig4a, fig4b = figure4(initial, out / "fig4.png")
    random_g_norms = np.array([_g_norm(random_placement(PARTICLES, rng, back_plane)) for _ in range(args.random)])
    figure5(fig3.final_g_norm, random_g_norms, out / "fig5.png")

    summary = {
        "seed": args.seed,
        "particles": PARTICLES,
        "sigma": 1.0,
        "r_d": 1.0,
        "dt_s": DT,
        "fig3_final_g_norm": fig3.final_g_norm,
        "fig4a_final_g_norm": fig4a.final_g_norm,
        "fig4b_final_g_norm": fig4b.final_g_norm,
        "random_placements": int(args.random),
        "random_g_norm_min": float(random_g_norms.min()),
        "random_g_norm_median": float(np.median(random_g_norms)),
        "random_g_norm_max": float(random_g_norms.max()),
        "share_random_worse": float(np.mean(random_g_norms > fig3.final_g_norm)),
        "bound_isotropic": PARTICLES / math.sqrt(3.0),
        "bound_great_circle": PARTICLES / math.sqrt(2.0),
        "paper_g_norm": PAPER_G_NORM,
    }
    if args.flight is not None:
        summary["flight"] = guidance_comparison(args.flight, out / "fig_flight_observability.png")
    write_summary(out / "summary.json", summary)
    print(f"wrote {out}: ||G||_F optimised {fig3.final_g_norm:.4f} (paper {PAPER_G_NORM}), "
          f"{100 * summary['share_random_worse']:.1f}% of {args.random} random placements worse")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
