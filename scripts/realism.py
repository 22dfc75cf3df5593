"""Realism check of the Kinect simulator: simulated streams beside real Kinect streams.

For every scenario, simulate a set of clean mocap clips and measure the raw stream against its
ground truth (FPG Eq. 13 bone-vector error: mean and Err0.2), the shares of inferred and not
tracked joints, per-joint jitter (mean acceleration magnitude) and bone-length variation (std
over time, mean over the 19 bones). Beside them, the same statistics (no error: no ground truth)
on the real MSRC-12 (Kinect v1) and Kinect v2 streams of ``../shared/data``.

Clips: with ``../shared/data`` present, nine in-place Bandai Namco dataset-1 takes (bow, bye,
byebye, guide, call, respond, punch, kick, slash; style ``normal``, take 001); otherwise the
embedded DeepMimic clips walk, run, jump, kick, punch, dance_a, dance_b, spinkick. Each clip
is simulated ``--repeats`` times with its own seeds (``--seed`` onwards).

UI-PRMD (with ``../shared/data``): the real Kinect v2 repetitions ``e05`` of every subject and
exercise, scored against their Vicon joint centres, beside the same Vicon motions simulated in
the ``front-kinect-v2`` scenario (the calibration target: raw error, jitter and bone-length
spread within 25 %, per joint group). The UI-PRMD hands are placeholders (the export has no
hand joint), so hand bones are left out of both sides.

Usage::

    python scripts/realism.py                 # markdown tables on stdout
    python scripts/realism.py --out realism.md
    python scripts/realism.py --quick         # two embedded clips, two scenarios (smoke test)
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fpg_gym.core import metrics, skeleton
from fpg_gym.core.skeleton import INFERRED, NOT_TRACKED, TRACKED
from fpg_gym.io import Clip, load_default_clips, read_clip, read_recording
from fpg_gym.io.kinect import SkippedLinesWarning
from fpg_gym.io.recording import Recording
from fpg_gym.simulate import KinectSimulator, scenario_names
from fpg_gym.simulate.models import JOINT_GROUP

REPO = Path(__file__).resolve().parents[1]
BANDAI_CONTENTS = ("bow", "bye", "byebye", "guide", "call", "respond", "punch", "kick", "slash")
DEFAULT_CLIPS = ("walk", "run", "jump", "kick", "punch", "dance_a", "dance_b", "spinkick")


def shared_data() -> Path | None:
    """``../shared/data`` (or ``$FPG_GYM_SHARED_DATA``) when it exists."""
    path = Path(os.environ.get("FPG_GYM_SHARED_DATA", REPO.parent / "shared" / "data"))
    return path if path.is_dir() else None


def choose_clips(data: Path | None, quick: bool = False) -> tuple[list[Clip], str]:
    """The clips to simulate and a sentence saying which they are."""
    if data is not None and not quick:
        folder = data / "bandai_namco" / "dataset-1"
        paths = [folder / f"dataset-1_{content}_normal_001.bvh" for content in BANDAI_CONTENTS]
        paths = [p for p in paths if p.is_file()]
        if paths:
            clips = [read_clip(p) for p in paths]
            return clips, (
                f"{len(clips)} Bandai Namco dataset-1 takes ({', '.join(BANDAI_CONTENTS)}; "
                "style normal, take 001)"
            )
    names = DEFAULT_CLIPS[:2] if quick else DEFAULT_CLIPS
    clips = load_default_clips(names)
    return clips, f"{len(clips)} embedded DeepMimic clips ({', '.join(names)})"


@dataclass
class Stats:
    """Pooled statistics of a set of streams (frame-weighted means)."""

    label: str
    frames: int = 0
    errors: list[np.ndarray] = field(default_factory=list)
    jitter: list[tuple[int, np.ndarray]] = field(default_factory=list)
    truth_jitter: list[tuple[int, np.ndarray]] = field(default_factory=list)
    bone_std: list[tuple[int, float]] = field(default_factory=list)
    inferred: int = 0
    not_tracked: int = 0
    joint_frames: int = 0
    seconds: float = 0.0

    def add(self, recording: Recording, seconds: float = 0.0) -> None:
        body = recording.body_present
        count = int(body.sum())
        self.frames += recording.num_frames
        self.seconds += seconds
        self.inferred += int(np.count_nonzero(recording.states == INFERRED))
        self.not_tracked += int(np.count_nonzero(recording.states == NOT_TRACKED))
        self.joint_frames += recording.states.size
        stamps = recording.timestamps
        if np.all(np.diff(stamps) > 0):
            jitter = metrics.jitter(recording.positions, timestamps=stamps, valid=body)
        else:
            jitter = metrics.jitter(recording.positions, fps=recording.fps, valid=body)
        self.jitter.append((count, jitter))
        self.bone_std.append(
            (count, float(np.nanmean(metrics.bone_length_variation(recording.positions[body]))))
        )
        if recording.ground_truth is not None:
            self.errors.append(metrics.frame_error(recording.ground_truth, recording.positions))
            self.truth_jitter.append(
                (count, metrics.jitter(recording.ground_truth, fps=recording.fps))
            )

    @staticmethod
    def _pool(items: list[tuple[int, np.ndarray]]) -> np.ndarray:
        weights = np.array([w for w, _ in items], dtype=np.float64)
        values = np.stack([np.asarray(v, dtype=np.float64) for _, v in items])
        ok = np.isfinite(values)
        shape = (-1,) + (1,) * (values.ndim - 1)
        w = np.where(ok, weights.reshape(shape), 0.0)
        return np.asarray((np.where(ok, values, 0.0) * w).sum(0) / np.maximum(w.sum(0), 1e-12))

    def row(self) -> dict[str, str]:
        error = np.concatenate(self.errors) if self.errors else None
        jitter = self._pool(self.jitter)
        bones = [(w, np.array(v)) for w, v in self.bone_std]
        truth = None
        if self.truth_jitter:
            pooled = self._pool(self.truth_jitter)
            truth = (float(pooled.mean()), float(pooled[list(_TORSO)].mean()))
        cells = {
            "stream": self.label,
            "frames": f"{self.frames}",
            "raw error (m)": f"{error.mean():.3f}" if error is not None else "—",
            "Err0.2 (%)": f"{100 * metrics.err_ratio(error):.1f}" if error is not None else "—",
            "inferred (%)": f"{100 * self.inferred / self.joint_frames:.1f}",
            "not tracked (%)": f"{100 * self.not_tracked / self.joint_frames:.1f}",
            "jitter (m/s²)": f"{jitter.mean():.1f}",
            "torso jitter (m/s²)": f"{jitter[list(_TORSO)].mean():.1f}",
            "truth jitter, all / torso (m/s²)": (
                f"{truth[0]:.1f} / {truth[1]:.1f}" if truth is not None else "—"
            ),
            "bone-length std (mm)": f"{1000 * self._pool(bones):.1f}",
            "ms/frame": f"{1000 * self.seconds / self.frames:.2f}" if self.seconds else "—",
        }
        return cells

    def joint_jitter(self) -> np.ndarray:
        return self._pool(self.jitter)


_TORSO = tuple(skeleton.joint_index(n) for n in ("HipCenter", "Spine", "ShoulderCenter", "Head"))


def markdown_table(rows: Sequence[dict[str, str]]) -> str:
    """A markdown table of rows sharing the same keys."""
    keys = list(rows[0])
    lines = ["| " + " | ".join(keys) + " |", "|" + "|".join(" --- " for _ in keys) + "|"]
    lines += ["| " + " | ".join(row[k] for k in keys) + " |" for row in rows]
    return "\n".join(lines)


def real_streams(data: Path) -> list[Stats]:
    """Statistics of the real MSRC-12 and Kinect v2 streams."""
    groups = [
        ("real MSRC-12 (Kinect v1, 3 files)", sorted((data / "msrc12").glob("*.csv"))),
        (
            "real Kinect v2 gestures (Ges01-05)",
            sorted((data / "kinect_v2_states").glob("Ges*.csv")),
        ),
        ("real Kinect v2 joints.csv (occluded)", [data / "kinect_v2_states" / "joints.csv"]),
    ]
    out = []
    for label, paths in groups:
        paths = [p for p in paths if p.is_file()]
        if not paths:
            continue
        stats = Stats(label)
        for path in paths:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SkippedLinesWarning)
                stats.add(read_recording(path))
        out.append(stats)
    return out


_GROUPS = ("core", "mid", "distal", "end")


def _group_stats(recordings: Sequence[Recording]) -> dict[str, tuple[float, float, float]]:
    """Per joint group (and ``all``): Eq. 13 error (cm), jitter (m/s²), bone-length std within
    a stream (mm); hand joints and bones left out."""
    errors, jitters, spreads = [], [], []
    for recording in recordings:
        assert recording.ground_truth is not None
        errors.append(metrics.per_joint_error(recording.ground_truth, recording.positions))
        jitters.append(metrics.jitter(recording.positions, fps=recording.fps))
        spreads.append(metrics.bone_length_variation(recording.positions))
    with warnings.catch_warnings():  # the root has no bone: its entries are NaN everywhere
        warnings.simplefilter("ignore", RuntimeWarning)
        error, jitter, spread = (np.nanmean(v, axis=0) for v in (errors, jitters, spreads))
    hand = np.array([n.startswith("Hand") for n in skeleton.JOINT_NAMES])
    out = {}
    for group in (*_GROUPS, "all"):
        joints = ~hand & np.array([group in ("all", g) for g in JOINT_GROUP])
        bones = joints[skeleton.BONES[:, 1]]
        out[group] = (
            100 * float(np.nanmean(error[joints])),
            float(np.nanmean(jitter[joints])),
            1000 * float(np.mean(spread[bones])),
        )
    return out


_LEGS = np.array([n.startswith(("Hip", "Knee", "Ankle", "Foot")) and n != "HipCenter"
                  for n in skeleton.JOINT_NAMES])  # fmt: skip


def state_row(label: str, recordings: Sequence[Recording]) -> dict[str, str]:
    """How a stream reports hidden joints, in numbers that depend little on the motion: the
    inferred share of the upper body and of the legs, the inferred runs of the upper body, and
    the jitter of a joint's inferred frames over that of its tracked frames (median over the
    joints with at least 20 frames of each)."""
    states = np.concatenate([r.states for r in recordings])
    upper_runs: list[int] = []
    tracked_sum, tracked_count = np.zeros(20), np.zeros(20)
    inferred_sum, inferred_count = np.zeros(20), np.zeros(20)
    for recording in recordings:
        magnitude = metrics.acceleration(recording.positions, fps=recording.fps)
        middle = recording.states[1:-1]
        for state, total, count in (
            (TRACKED, tracked_sum, tracked_count),
            (INFERRED, inferred_sum, inferred_count),
        ):
            total += np.where(middle == state, magnitude, 0.0).sum(axis=0)
            count += (middle == state).sum(axis=0)
        inferred = (recording.states[:, ~_LEGS] == INFERRED).astype(np.int8)
        edges = np.diff(np.pad(inferred, ((1, 1), (0, 0))), axis=0)
        for joint in range(inferred.shape[1]):
            starts, ends = (
                np.flatnonzero(edges[:, joint] == 1),
                np.flatnonzero(edges[:, joint] == -1),
            )
            upper_runs.extend((ends - starts).tolist())
    both = (tracked_count >= 20) & (inferred_count >= 20)
    ratio = (inferred_sum[both] / inferred_count[both]) / (tracked_sum[both] / tracked_count[both])
    runs = np.array(upper_runs)
    return {
        "stream": label,
        "inferred, upper body (%)": f"{100 * np.mean(states[:, ~_LEGS] == INFERRED):.1f}",
        "inferred, legs (%)": f"{100 * np.mean(states[:, _LEGS] == INFERRED):.1f}",
        "upper-body inferred runs of 1-4 frames (%)": (
            f"{100 * np.mean(runs <= 4):.0f} of {len(runs)}" if len(runs) else "—"
        ),
        "jitter inferred / tracked, same joint": (
            f"{np.median(ratio):.2f} ({int(both.sum())} joints)" if both.any() else "—"
        ),
    }


def uiprmd_realism(data: Path, scenario: str = "front-kinect-v2", repetition: int = 5) -> str:
    """Real UI-PRMD Kinect v2 against the simulator on the same Vicon motions (markdown)."""
    from fpg_gym.io.ui_prmd_import import find_repetitions, pair_repetitions

    root = data / "ui_prmd"
    real, simulated = [], []
    sessions = find_repetitions(root)
    with KinectSimulator(scenario) as simulator:
        for number, reps in enumerate(sessions.values()):
            paired, _ = pair_repetitions(root, reps)
            for pair in paired:
                if pair.repetition.repetition != repetition:
                    continue
                real.append(pair.recording)
                truth = pair.recording.ground_truth
                clip = Clip(pair.repetition.name, truth, fps=pair.recording.fps)
                simulated.append(simulator.simulate(clip, seed=number))
    real_stats, sim_stats = _group_stats(real), _group_stats(simulated)
    rows = []
    for group in ("all", *_GROUPS):
        row = {"joints": "feet" if group == "end" else group}
        for name, column in enumerate(("raw error (cm)", "jitter (m/s²)", "bone std (mm)")):
            r, s = real_stats[group][name], sim_stats[group][name]
            flag = "" if abs(s / r - 1) <= 0.25 else " ✗"
            row[column] = f"{r:.1f} / {s:.1f} ({s / r:.2f}){flag}"
        rows.append(row)
    return "\n".join(
        [
            f"UI-PRMD: {len(real)} real Kinect v2 repetitions (e{repetition:02d} of every "
            f"session) scored against Vicon, / the same Vicon motions simulated in "
            f"`{scenario}` (ratio sim/real; ✗ beyond 25 %). Hands left out (placeholders).",
            "",
            markdown_table(rows),
        ]
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenarios", nargs="+", default=None, help="default: all")
    parser.add_argument("--seed", type=int, default=0, help="first seed")
    parser.add_argument("--repeats", type=int, default=3, help="seeds per clip (default 3)")
    parser.add_argument("--quick", action="store_true", help="2 embedded clips, 2 scenarios")
    parser.add_argument("--out", type=Path, default=None, help="also write the tables here")
    args = parser.parse_args(argv)

    from tqdm.auto import tqdm

    data = shared_data()
    clips, clip_text = choose_clips(data, quick=args.quick)
    names = args.scenarios or (["clean", "front-many"] if args.quick else list(scenario_names()))
    simulated: list[Stats] = []
    repeats = 1 if args.quick else max(1, args.repeats)
    total = len(names) * len(clips) * repeats
    bar = tqdm(total=total, desc="simulating", unit="run", file=sys.stderr)
    for name in names:
        stats = Stats(f"sim {name}")
        with KinectSimulator(name) as simulator:
            for index, clip in enumerate(clips):
                for repeat in range(repeats):
                    start = time.perf_counter()
                    seed = args.seed + index * repeats + repeat
                    recording = simulator.simulate(clip, seed=seed)
                    stats.add(recording, time.perf_counter() - start)
                    bar.update()
        simulated.append(stats)
    bar.close()
    real = real_streams(data) if data is not None and not args.quick else []
    every = simulated + real
    lines = [
        f"Simulated: {clip_text}, {repeats} seed(s) each "
        f"({args.seed}..{args.seed + len(clips) * repeats - 1}). "
        + (
            "Real: `../shared/data` msrc12 and kinect_v2_states."
            if real
            else "Real streams: `../shared/data` absent, not measured."
        ),
        "",
        markdown_table([s.row() for s in every]),
        "",
        "Per-joint jitter (mean acceleration magnitude, m/s²):",
        "",
    ]
    joint_rows = []
    for joint, name in enumerate(skeleton.JOINT_NAMES):
        row = {"joint": name}
        for stats in every:
            row[stats.label.replace("sim ", "").replace("real ", "")] = (
                f"{stats.joint_jitter()[joint]:.1f}"
            )
        joint_rows.append(row)
    lines.append(markdown_table(joint_rows))
    if data is not None and (data / "ui_prmd").is_dir() and not args.quick:
        lines += ["", uiprmd_realism(data)]
    occluded = data / "kinect_v2_states" / "joints.csv" if data is not None else None
    if occluded is not None and occluded.is_file() and "front-many-kinect-v2" in names:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkippedLinesWarning)
            real_occluded = read_recording(occluded)
        with KinectSimulator("front-many-kinect-v2") as simulator:
            simulated_occluded = [
                simulator.simulate(clip, seed=args.seed + index) for index, clip in enumerate(clips)
            ]
        lines += [
            "",
            "Tracking states of the occluded Kinect v2 (`joints.csv`) beside "
            "`front-many-kinect-v2` on the clips above (one seed each):",
            "",
            markdown_table(
                [
                    state_row("sim front-many-kinect-v2", simulated_occluded),
                    state_row("real Kinect v2 joints.csv (occluded)", [real_occluded]),
                ]
            ),
        ]
    text = "\n".join(lines)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
