"""``fpg-gym demo``: the whole job on the embedded data, with no user files.

1. The default pose graph of the embedded DeepMimic clips, built without the held-out clips
   :data:`fpg_gym.defaults.DEFAULT_HOLDOUT_CLIPS` (walk, punch, kick, dance_b) and cached.
2. Kinect streams simulated from the held-out clips in the scenarios
   :data:`fpg_gym.defaults.DEFAULT_EPISODE_SCENARIOS` (front, 45° left and right, many
   occluders): 12 episodes with ground truth.
3. Every method of :data:`DEMO_METHODS` on every episode (:func:`fpg_gym.experiments.run_compare`):
   the sensor as is, the Kinect SDK and Kalman filters, the graph selection with no search,
   random search and the papers' local search (the baseline), Shum's brute-force selection, the
   baseline with the ragdoll, and two methods beyond the papers: the closed-form minimiser of the
   quadratic energy terms (one evaluation) and local search with the latent prior.
4. The comparison table, the compare plots and an animated GIF of one episode: the simulated
   Kinect input (joints coloured by tracking state), the reconstruction and the ground truth
   side by side; with rerun-sdk installed (``fpg-gym[view]``) also ``demo.rrd``, the same
   episode in 3D with every reconstruction method (:mod:`fpg_gym.experiments.view`).

About 24 CPU seconds with numba (README: the measured wall time and its load). ``quick=True``
runs a reduced version (two clips, one scenario, 24 frames, four methods) in a few seconds,
for tests.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fpg_gym.defaults import DEFAULT_EPISODE_SCENARIOS, DEFAULT_HOLDOUT_CLIPS
from fpg_gym.experiments import CompareConfig, CompareOutcome, format_tests, plots, run_compare
from fpg_gym.experiments.store import frames_path, load_frames
from fpg_gym.experiments.view import rerun_available, write_view
from fpg_gym.io.recording import load_recording

__all__ = ["DEMO_METHODS", "QUICK_METHODS", "DemoOutcome", "run_demo"]

#: Methods of the full demo (see :mod:`fpg_gym.methods` for the names).
DEMO_METHODS: tuple[str, ...] = (
    "raw",
    "holt",
    "kalman",
    "fpg:none",
    "fpg:random-search",
    "fpg:local-search",
    "shum:local-search",
    "fpg:local-search+ragdoll",
    "fpg:closed-form",
    "fpg:local-search+prior",
)
#: Methods of ``quick=True``.
QUICK_METHODS: tuple[str, ...] = ("raw", "holt", "fpg:none", "fpg:local-search")
#: Episode shown in the GIF (clip, scenario), when it was run.
GIF_EPISODE: tuple[str, str] = ("dance_b", "front-many")


@dataclass
class DemoOutcome:
    """What :func:`run_demo` did: the comparison, the GIF and the time taken."""

    compare: CompareOutcome
    gif: Path | None
    snapshot: Path | None
    gif_episode: str
    gif_method: str
    seconds: float
    view: Path | None = None

    @property
    def files(self) -> list[Path]:
        """Every file written at the top of the output folder."""
        return sorted(p for p in self.compare.out.iterdir() if p.is_file())


def _gif_method(methods: Sequence[str]) -> str:
    for name in ("fpg:local-search+ragdoll", "fpg:local-search"):
        if name in methods:
            return name
    reconstruction = [m for m in methods if m.startswith(("fpg", "shum"))]
    return reconstruction[0] if reconstruction else methods[-1]


def _pick_episode(summary: dict[str, Any], episodes: list[dict[str, Any]]) -> str:
    done = set(summary["episodes"])
    for e in episodes:
        if (e["clip"], e["scenario"]) == GIF_EPISODE and e["id"] in done:
            return str(e["id"])
    return str(summary["episodes"][0]) if summary["episodes"] else ""


def write_animation(
    out: Path, episode: str, method: str, *, fps: float = 30.0, max_frames: int | None = None
) -> tuple[Path, Path]:
    """GIF and one-frame PNG of an episode: Kinect input, ``method``'s output, ground truth."""

    recording = load_recording(out / "episodes" / f"{episode}.npz")
    poses = load_frames(frames_path(out, episode, method))["poses"]
    count = len(poses) if max_frames is None else min(len(poses), max_frames)
    truth = recording.ground_truth
    assert truth is not None
    panels = {
        "Kinect input (simulated)": recording.positions[:count],
        f"reconstruction ({method})": poses[:count],
        "ground truth": truth[:count],
    }
    frames = plots.skeleton_animation(
        panels,
        states=recording.states[:count],
        states_panel="Kinect input (simulated)",
        fps=fps,
        title=f"{episode}: joints green tracked, orange inferred, red not tracked",
    )
    gif = plots.save_gif(out / "demo.gif", frames, fps=fps)
    png = plots.save_png(out / "demo_frame.png", frames[count // 2])
    return gif, png


def write_demo_view(out: Path, episode: str, methods: Sequence[str]) -> Path:
    """``demo.rrd``: an episode in 3D with the output of every method that is not the raw
    input (:func:`fpg_gym.experiments.view.write_view`)."""
    recording = load_recording(out / "episodes" / f"{episode}.npz")
    shown = {}
    for method in methods:
        path = frames_path(out, episode, method)
        if method != "raw" and path.is_file():
            shown[method] = load_frames(path, ["poses"])["poses"]
    return write_view(
        out / "demo.rrd",
        recording.positions,
        recording.states,
        recording.timestamps,
        reconstructions=shown,
        ground_truth=recording.ground_truth,
    )


def run_demo(
    out: str | Path = "fpg-gym-demo",
    *,
    quick: bool = False,
    methods: Sequence[str] | None = None,
    workers: int | None = None,
    seed: int = 0,
    progress: bool = True,
    gif: bool = True,
    view: bool = True,
) -> DemoOutcome:
    """Run the demo (see the module docstring) and write everything to ``out``.

    Parameters
    ----------
    out : str or Path
        Output folder (earlier demo results in it are replaced).
    quick : bool
        The reduced version (for tests).
    methods : sequence of str, optional
        Override :data:`DEMO_METHODS` / :data:`QUICK_METHODS`.
    workers : int, optional
        Processes; ``min(2, CPU count)`` by default (1 runs in this process).
    seed : int
        Simulator and optimiser seed.
    gif : bool
        Write ``demo.gif`` and ``demo_frame.png``.
    view : bool
        Write ``demo.rrd`` (the 3D view) when rerun-sdk is installed.
    """

    started = time.perf_counter()
    chosen = list(methods) if methods else list(QUICK_METHODS if quick else DEMO_METHODS)
    if workers is None:
        workers = 1 if quick else min(2, os.cpu_count() or 1)
    config = CompareConfig(
        out=str(out),
        methods=chosen,
        graph="default",
        clips=[
            f"default:{n}" for n in (DEFAULT_HOLDOUT_CLIPS[:2] if quick else DEFAULT_HOLDOUT_CLIPS)
        ],
        scenarios=list(DEFAULT_EPISODE_SCENARIOS[:1] if quick else DEFAULT_EPISODE_SCENARIOS),
        seeds=[seed],
        max_frames=24 if quick else None,
        workers=workers,
    )
    outcome = run_compare(config, progress=progress, fresh=True)
    gif_path = png_path = None
    episode = ""
    method = _gif_method(config.methods)
    if gif and outcome.summary["episodes"]:
        episodes = json.loads((outcome.out / "config.json").read_text())["episodes"]
        episode = _pick_episode(outcome.summary, episodes)
        try:
            gif_path, png_path = write_animation(outcome.out, episode, method)
        except FileNotFoundError:  # interrupted before that run finished
            gif_path = png_path = None
    view_path = None
    if view and rerun_available() and outcome.summary["episodes"]:
        if not episode:
            episodes = json.loads((outcome.out / "config.json").read_text())["episodes"]
            episode = _pick_episode(outcome.summary, episodes)
        view_path = write_demo_view(outcome.out, episode, config.methods)
    return DemoOutcome(
        compare=outcome,
        gif=gif_path,
        snapshot=png_path,
        gif_episode=episode,
        gif_method=method,
        seconds=time.perf_counter() - started,
        view=view_path,
    )


def print_outcome(outcome: DemoOutcome) -> None:
    """Print the demo's table, paired tests, files and time (what ``fpg-gym demo`` shows)."""
    summary = outcome.compare.summary
    print(
        f"fpg-gym demo: embedded graph without the held-out clips "
        f"{', '.join(summary['clips'])}; {len(summary['episodes'])} simulated episodes "
        f"({', '.join(summary['scenarios'])})"
    )
    print(f"graph: {summary['graph']}")
    print()
    print(outcome.compare.table)
    print()
    if summary.get("input_mean_error_m") is not None:
        print(f"simulated Kinect input: mean error {summary['input_mean_error_m']:.3f} m")
    jitter = summary.get("ground_truth_jitter_ms2")
    if jitter is not None:
        print(f"ground-truth jitter (the motion's own acceleration): {jitter:.1f} m/s²")
    print()
    print(f"paired test against {summary['baseline']} (Wilcoxon signed-rank over episodes):")
    print(format_tests(summary))
    print()
    print(f"written to {outcome.compare.out}/:")
    for path in outcome.files:
        print(f"  {path.name}")
    if outcome.gif is not None:
        print(f"  (GIF: episode {outcome.gif_episode}, method {outcome.gif_method})")
    if outcome.view is not None:
        print(f"  (3D view: episode {outcome.gif_episode}; open with: rerun {outcome.view})")
    state = " (interrupted)" if outcome.compare.interrupted else ""
    print(f"time: {outcome.seconds:.1f} s{state}")
