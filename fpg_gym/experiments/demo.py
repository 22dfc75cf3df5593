"""``fpg-gym demo``: the whole job on the packaged data, with no user files.

0. **Real Kinect v2 streams first.** Four real UI-PRMD repetitions shipped in the package
   (``fpg_gym/data/demo``: subject s08, whom no packaged database, map or model has seen; a
   squat, a hurdle step, a sit to stand and a shoulder abduction) with their Vicon joint centres,
   as they are and with each occlusion case of :mod:`fpg_gym.simulate.occlude` put into them:
   the raw sensor, the Kinect SDK's Holt filter, the mapped sensor with Holt and the default
   pipeline (``fpg:closed-form``, the ``auto`` preset of a Kinect v2:
   :mod:`fpg_gym.reconstruct.presets`), scored against Vicon with Eq. 13, MPJPE and the rest
   (``real/clean`` and ``real/occluded``, compare folders of their own; ``headline.md``, the
   README's headline table). The GIF shows a real squat whose lower legs are lost.
1. The default pose graph of the embedded DeepMimic clips, built without the held-out clips
   :data:`fpg_gym.core.defaults.DEFAULT_HOLDOUT_CLIPS` (walk, punch, kick, dance_b) and cached.
2. Kinect streams simulated from the held-out clips in the scenarios
   :data:`fpg_gym.core.defaults.DEFAULT_EPISODE_SCENARIOS` (front, 45° left and right, many
   occluders): 12 episodes with ground truth.
3. Every method of :data:`DEMO_METHODS` on every episode (:func:`fpg_gym.experiments.run_compare`):
   the sensor as is, the Kinect SDK and Kalman filters, the graph selection with no search,
   random search and the papers' local search (the baseline), Shum's brute-force selection, the
   baseline with the ragdoll, and two methods beyond the papers: the closed-form minimiser of the
   quadratic energy terms (one evaluation) and local search with the latent prior.
4. The comparison table, the compare plots and an animated GIF of one episode: the real
   Kinect input (joints coloured by tracking state, occluded), the default pipeline's output and
   the Vicon truth side by side; with rerun-sdk installed (``fpg-gym[view]``) also ``demo.rrd``,
   the same episode in 3D with every method (:mod:`fpg_gym.experiments.view`). ``report.md``
   puts the real sections first, then the simulated comparison.

About 24 CPU seconds with numba (README: the measured wall time and its load). On a fresh
installation (numba's cache cold) it runs the kernels' numpy versions, a few CPU seconds more,
while :func:`fpg_gym.experiments.warm.compile_in_background` compiles them for later runs.
``quick=True`` runs a reduced version (two real repetitions, one occlusion; two clips, one
scenario, 24 frames, four methods) in a few seconds, for tests.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fpg_gym.core.compiled import numpy_only
from fpg_gym.core.defaults import DEFAULT_EPISODE_SCENARIOS, DEFAULT_HOLDOUT_CLIPS
from fpg_gym.core.seeding import derive_seed
from fpg_gym.experiments import CompareConfig, CompareOutcome, format_tests, plots, run_compare
from fpg_gym.experiments.report import markdown_table
from fpg_gym.experiments.store import frames_path, load_frames
from fpg_gym.experiments.view import rerun_available, write_view
from fpg_gym.experiments.warm import compile_in_background, warm_kernels_cached
from fpg_gym.io.recording import load_recording, write_recording
from fpg_gym.simulate.occlude import OCCLUSION_CASES, occlude

__all__ = [
    "DEMO_METHODS",
    "QUICK_METHODS",
    "REAL_METHODS",
    "DemoOutcome",
    "demo_recordings",
    "run_demo",
]

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
#: Methods of the real sections (the baseline of their tests: what a Kinect user already has).
REAL_METHODS: tuple[str, ...] = ("raw", "holt", "holt+map", "fpg:closed-form")
REAL_BASELINE = "holt+map"
#: ``quick=True`` draws every third frame of the GIF (the drawing is most of its time).
QUICK_GIF_STEP = 3
#: The real episode of the GIF: a squat whose lower legs are lost.
GIF_REAL_EPISODE = "m01_s08_e05-legs"
_DEMO_DATA = Path(__file__).resolve().parents[1] / "data" / "demo"


def demo_recordings() -> list[Path]:
    """The real UI-PRMD repetitions shipped for the demo (``fpg_gym/data/demo``)."""
    return sorted(_DEMO_DATA.glob("*.npz"))


#: Said in the output when the kernels were not compiled yet: the numpy versions sum in other
#: orders, and the local search can then take other steps (docs/performance.md, cold start).
_NUMPY_KERNELS_NOTE = (
    "numba's kernels were not compiled yet: this run used their numpy versions (the same "
    "equations, summed in other orders: a local search can take other steps, so its episodes' "
    "figures may differ by a few percent from a later run's)"
)


@dataclass
class DemoOutcome:
    """What :func:`run_demo` did: the comparisons (real first), the GIF, the time taken and the
    process compiling the kernels in the background (``compiling``: its pid; None when they
    were compiled already)."""

    compare: CompareOutcome
    gif: Path | None
    snapshot: Path | None
    gif_episode: str
    gif_method: str
    seconds: float
    view: Path | None = None
    real_clean: CompareOutcome | None = None
    real_occluded: CompareOutcome | None = None
    headline: Path | None = None
    compiling: int | None = None

    @property
    def files(self) -> list[Path]:
        """Every file written at the top of the output folder."""
        return sorted(p for p in self.compare.out.iterdir() if p.is_file())


def real_inputs(
    folder: Path, *, quick: bool = False, seed: int = 0
) -> tuple[list[Path], list[Path]]:
    """The demo's real repetitions as they are, and with each occlusion case put into them
    (written to ``folder``; ``quick``: two repetitions, the lost legs only)."""
    clean = demo_recordings()[:2] if quick else demo_recordings()
    folder.mkdir(parents=True, exist_ok=True)
    occluded = []
    for path in clean:
        recording = load_recording(path)
        for case in ("legs",) if quick else tuple(OCCLUSION_CASES):
            target = folder / f"{path.stem}-{case}.npz"
            seeded = derive_seed(seed, path.stem, case)
            occluded.append(write_recording(target, occlude(recording, case, seeded)))
    return clean, occluded


def _real_compare(
    out: Path,
    inputs: Sequence[Path],
    methods: Sequence[str],
    workers: int,
    seed: int,
    progress: bool,
) -> CompareOutcome:
    config = CompareConfig(
        out=str(out),
        methods=list(methods),
        graph="default",  # the sensor's: the packaged UI-PRMD database, s08 never in it
        inputs=[str(p) for p in inputs],
        seeds=[seed],
        workers=workers,
        baseline=REAL_BASELINE,
    )
    return run_compare(config, progress=progress, fresh=True)


def headline_table(clean: dict[str, Any], occluded: dict[str, Any]) -> str:
    """The README's headline table: each real method's error, as is and occluded, against the
    raw sensor (Eq. 13, MPJPE, the occluded joints' MPJPE, jitter)."""

    def ratio(summary: dict[str, Any], method: str, key: str) -> str:
        value, raw = summary["methods"][method].get(key), summary["methods"]["raw"].get(key)
        return "–" if value is None or not raw else f"{value:.3f} m ({value / raw:.2f}×)"

    def jitter(method: str) -> str:
        value, raw = (clean["methods"][m]["jitter_ms2"] for m in (method, "raw"))
        return "–" if value is None or not raw else f"{value / raw:.2f}×"

    rows = []
    for method in clean["method_order"]:
        rows.append(
            [
                f"`{method}`",
                ratio(clean, method, "mean_error_m"),
                ratio(clean, method, "mpjpe_m"),
                ratio(occluded, method, "mpjpe_m"),
                ratio(occluded, method, "occluded_mpjpe_m"),
                jitter(method),
            ]
        )
    columns = [
        "method",
        "Eq. 13, no occlusion",
        "MPJPE, no occlusion",
        "MPJPE, occluded streams",
        "occluded joints' MPJPE",
        "jitter",
    ]
    return markdown_table(columns, rows)


def _write_report(out: Path, outcome: DemoOutcome) -> None:
    """``report.md``: the real sections first (their tables and tests), then the simulated
    comparison's own report."""
    simulated = (out / "report.md").read_text(encoding="utf-8")
    lines = ["# fpg-gym demo", ""]
    if outcome.compiling is not None:
        lines += [f"{_NUMPY_KERNELS_NOTE}; the times below are numpy's.", ""]
    for title, part in (
        ("Real Kinect v2 streams, as they are", outcome.real_clean),
        ("Real Kinect v2 streams with occlusions put into them", outcome.real_occluded),
    ):
        if part is None:
            continue
        summary = part.summary
        folder = part.out.relative_to(out).as_posix()
        lines += [
            f"## {title} (`{folder}`)",
            "",
            f"UI-PRMD subject s08 (never in a packaged database, map or model), "
            f"{len(summary['episodes'])} episodes, scored against Vicon joint centres; "
            f"{summary['graph']}.",
            "",
            part.table,
            "",
            f"Paired test against `{summary['baseline']}` (what a Kinect user already has):",
            "",
            format_tests(summary),
            "",
            f"Plots: [{folder}/error_over_time.png]({folder}/error_over_time.png), "
            f"[{folder}/cumulative.png]({folder}/cumulative.png); full report: "
            f"[{folder}/report.md]({folder}/report.md).",
            "",
        ]
    lines += ["## Simulated streams of the embedded clips", ""]
    body = simulated.split("\n", 1)[1] if simulated.startswith("# ") else simulated
    lines.append(body.replace("\n## ", "\n### "))
    (out / "report.md").write_text("\n".join(lines), encoding="utf-8")


def write_animation(
    out: Path,
    episode: str,
    method: str,
    *,
    fps: float = 30.0,
    max_frames: int | None = None,
    target: Path | None = None,
    source: str = "simulated",
    truth_label: str = "ground truth",
    step: int = 1,
) -> tuple[Path, Path]:
    """GIF and one-frame PNG of an episode of the compare folder ``out``: Kinect input,
    ``method``'s output, ground truth (written to ``target``, ``out`` by default; every
    ``step``-th frame, at ``fps / step``)."""

    recording = load_recording(out / "episodes" / f"{episode}.npz")
    poses = load_frames(frames_path(out, episode, method))["poses"]
    count = len(poses) if max_frames is None else min(len(poses), max_frames)
    truth = recording.ground_truth
    assert truth is not None
    label = f"Kinect input ({source})"
    shown = slice(0, count, step)
    panels = {
        label: recording.positions[shown],
        f"reconstruction ({method})": poses[shown],
        truth_label: truth[shown],
    }
    frames = plots.skeleton_animation(
        panels,
        states=recording.states[shown],
        states_panel=label,
        fps=fps / step,
        title=f"{episode}: joints green tracked, orange inferred, red not tracked",
    )
    folder = out if target is None else target
    gif = plots.save_gif(folder / "demo.gif", frames, fps=fps / step)
    png = plots.save_png(folder / "demo_frame.png", frames[len(frames) // 2])
    return gif, png


def write_demo_view(
    out: Path, episode: str, methods: Sequence[str], target: Path | None = None
) -> Path:
    """``demo.rrd`` (in ``target``, ``out`` by default): an episode of the compare folder
    ``out`` in 3D with the output of every method that is not the raw input
    (:func:`fpg_gym.experiments.view.write_view`)."""
    recording = load_recording(out / "episodes" / f"{episode}.npz")
    shown = {}
    for method in methods:
        path = frames_path(out, episode, method)
        if method != "raw" and path.is_file():
            shown[method] = load_frames(path, ["poses"])["poses"]
    return write_view(
        (out if target is None else target) / "demo.rrd",
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
    out = Path(out)
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
    cold = not warm_kernels_cached()
    # A fresh installation: the demo's frames take less time with the kernels' numpy versions
    # than compiling the kernels first would (docs/performance.md, cold start); they compile
    # meanwhile for later runs.
    compiling = compile_in_background().pid if cold else None
    with numpy_only(new_processes=True) if cold else contextlib.nullcontext():
        outcome = run_compare(config, progress=progress, fresh=True)
        # The real sections in folders of their own, inside the simulated comparison's (whose
        # manifest makes the folder compare's own).
        real = out / "real"
        clean_inputs, occluded_inputs = real_inputs(real / "inputs", quick=quick, seed=seed)
        real_methods = [m for m in REAL_METHODS if not quick or m != "holt"]
        real_clean = _real_compare(
            real / "clean", clean_inputs, real_methods, workers, seed, progress
        )
        real_occluded = _real_compare(
            real / "occluded", occluded_inputs, real_methods, workers, seed, progress
        )
    gif_path = png_path = None
    episode = f"{GIF_REAL_EPISODE}__s{seed}"  # compare's id of a recording episode
    method = REAL_METHODS[-1]
    if gif and episode in real_occluded.summary["episodes"]:
        try:
            gif_path, png_path = write_animation(
                real_occluded.out,
                episode,
                method,
                target=out,
                source="real, lower legs lost",
                truth_label="Vicon truth",
                step=QUICK_GIF_STEP if quick else 1,
            )
        except FileNotFoundError:  # interrupted before that run finished
            gif_path = png_path = None
    view_path = None
    if view and rerun_available() and episode in real_occluded.summary["episodes"]:
        view_path = write_demo_view(real_occluded.out, episode, real_methods, target=out)
    headline = out / "headline.md"
    headline.write_text(
        headline_table(real_clean.summary, real_occluded.summary) + "\n", encoding="utf-8"
    )
    result = DemoOutcome(
        compare=outcome,
        gif=gif_path,
        snapshot=png_path,
        gif_episode=episode,
        gif_method=method,
        seconds=time.perf_counter() - started,
        view=view_path,
        real_clean=real_clean,
        real_occluded=real_occluded,
        headline=headline,
        compiling=compiling,
    )
    _write_report(out, result)
    return result


def print_outcome(outcome: DemoOutcome) -> None:
    """Print the demo's tables (real first), paired tests, files and time (what
    ``fpg-gym demo`` shows)."""
    for title, part in (
        ("real Kinect v2 streams of UI-PRMD s08, as they are", outcome.real_clean),
        ("the same with occlusions put into them", outcome.real_occluded),
    ):
        if part is None:
            continue
        print(f"fpg-gym demo: {title}; {len(part.summary['episodes'])} episodes against Vicon")
        print()
        print(part.table)
        print()
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
    if outcome.compiling is not None:
        print(
            f"{_NUMPY_KERNELS_NOTE}; a process at the lowest priority (pid {outcome.compiling}) "
            "is compiling them for later runs (`fpg-gym warm-up` does it in the foreground)"
        )
