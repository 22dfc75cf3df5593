"""Import UI-PRMD: pair every Kinect repetition with its Vicon repetition and write files.

For each session (one exercise of one subject, one camera placement) the Vicon joint centres
(:func:`fpg_gym.io.ui_prmd.vicon_joint_centres`) are resampled from 100 to 30 Hz, then
:func:`fpg_gym.core.pairing.pair_session` finds each repetition's lag and one rigid transform of the
session from Vicon space into the Kinect's camera space. Written under ``OUT``:

``recordings/mMM_sSS_eEE.npz``
    The real Kinect stream (:class:`~fpg_gym.io.recording.Recording`), cut to the frames that
    have a Vicon frame, with the Vicon joint centres in the Kinect's space as ``ground_truth``.
``clips/mMM_sSS_eEE.npz``
    The whole Vicon repetition's joint centres at 30 Hz (a positions clip, readable by
    ``build-graph``), in the same space.
``import.json``
    Per session: alignment error, lags, frames, the Vicon pelvis width; repetitions skipped and
    why; warnings (a pelvis width outside :data:`~fpg_gym.io.ui_prmd.PLAUSIBLE_PELVIS_WIDTH_M`,
    whose hip centres, and so ``HipCenter`` and the hip and spine bones of the ground truth,
    are suspect; an alignment error that is an outlier among the import's sessions,
    :func:`flag_alignment_outliers`: a marker, a joint centre or the Kinect's tracking is then
    suspect; the session is still written).

Every file is written to a temporary name and renamed into place, so an interrupted import
leaves complete files only (re-running the import rewrites the same files).
"""

from __future__ import annotations

import json
import os
import re
import warnings
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from fpg_gym.core import poses
from fpg_gym.core.errors import DataFormatError, OutputError
from fpg_gym.core.metrics import robust_z_scores
from fpg_gym.core.outputs import write_text
from fpg_gym.core.pairing import apply_rigid, overlap, pair_session
from fpg_gym.io.clip import Clip
from fpg_gym.io.files import read_json
from fpg_gym.io.positions import write_positions
from fpg_gym.io.recording import Recording, write_recording
from fpg_gym.io.ui_prmd import (
    JOINT_CENTRE_RULE,
    KINECT_FPS,
    PLAUSIBLE_PELVIS_WIDTH_M,
    VICON_FPS,
    RepetitionId,
    parse_repetition_name,
    pelvis_width,
    read_kinect_repetition,
    read_vicon_markers,
    vicon_joint_centres,
)

__all__ = [
    "ALIGNMENT_OUTLIER_Z",
    "MAX_ALIGNMENT_M",
    "PairedRepetition",
    "SessionReport",
    "find_repetitions",
    "flag_alignment_outliers",
    "import_uiprmd",
    "pair_repetitions",
]

_KINECT_POSITIONS = Path("Kinect") / "Positions"
_KINECT_ANGLES = Path("Kinect") / "Angles"
_VICON_POSITIONS = Path("Vicon") / "Positions"
_SUBJECT = re.compile(r"^s\d+$")

#: A session's mean alignment error whose robust z-score against the import's sessions exceeds
#: this is an outlier (Iglewicz & Hoaglin's rule, :func:`fpg_gym.core.metrics.robust_z_scores`),
#: when at least :data:`MIN_SESSIONS_COMPARED` sessions are compared.
ALIGNMENT_OUTLIER_Z = 3.5
MIN_SESSIONS_COMPARED = 5
#: A session's mean alignment error above this is an outlier however many sessions are imported
#: (metres; UI-PRMD's sessions: median 55 mm, 39-117 mm but for two).
MAX_ALIGNMENT_M = 0.15


@dataclass(frozen=True)
class PairedRepetition:
    """A Kinect repetition with its Vicon joint centres in the Kinect's space."""

    repetition: RepetitionId
    recording: Recording
    reference: np.ndarray  # (U, 20, 3) Vicon joint centres at 30 Hz, Kinect space
    lag: int
    distance_m: float


@dataclass
class SessionReport:
    """What the import did with one session."""

    session: str
    repetitions: list[str] = field(default_factory=list)
    lags: list[int] = field(default_factory=list)
    alignment_m: list[float] = field(default_factory=list)
    frames: list[int] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    pelvis_width_m: float | None = None
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {
            "session": self.session,
            "repetitions": self.repetitions,
            "lags": self.lags,
            "alignment_m": [round(v, 5) for v in self.alignment_m],
            "mean_alignment_m": round(float(np.mean(self.alignment_m)), 5)
            if self.alignment_m
            else None,
            "frames": self.frames,
            "skipped": self.skipped,
            "pelvis_width_m": None
            if self.pelvis_width_m is None
            else round(self.pelvis_width_m, 4),
            "warnings": self.warnings,
        }


def _root_folder(root: Path) -> Path:
    """The folder holding ``Kinect/`` and ``Vicon/`` (``root`` or its ``Segmented Movements``)."""
    for candidate in (root, root / "Segmented Movements"):
        if (candidate / _KINECT_POSITIONS).is_dir():
            return candidate
    raise FileNotFoundError(
        f"{root}: not a UI-PRMD folder; expected Kinect/Positions (or 'Segmented Movements/"
        "Kinect/Positions') inside it"
    )


def find_repetitions(
    root: str | Path, subjects: Iterable[str] | None = None
) -> dict[str, list[RepetitionId]]:
    """Kinect repetitions under ``root``, grouped by session, for the given subjects (all).

    Raises
    ------
    FileNotFoundError
        If ``root`` is not a UI-PRMD folder or holds no repetition of the subjects.
    ValueError
        If a subject is not written ``sNN``.
    """
    folder = _root_folder(Path(root))
    wanted: set[int] | None = None
    if subjects is not None:
        wanted = set()
        for name in subjects:
            if not _SUBJECT.match(name):
                raise ValueError(f"--subjects: expected names like s01, got {name!r}")
            wanted.add(int(name[1:]))
    sessions: dict[str, list[RepetitionId]] = {}
    for path in sorted((folder / _KINECT_POSITIONS).iterdir()):
        try:
            rep = parse_repetition_name(path)
        except DataFormatError:
            continue
        if wanted is None or rep.subject in wanted:
            sessions.setdefault(rep.session, []).append(rep)
    if not sessions:
        raise FileNotFoundError(
            f"{folder}: no Kinect repetition of subjects {sorted(wanted or [])}"
        )
    return sessions


def _files(folder: Path, rep: RepetitionId) -> tuple[Path, Path, Path]:
    stem = rep.name
    return (
        folder / _KINECT_POSITIONS / f"{stem}_positions.txt.gz",
        folder / _KINECT_ANGLES / f"{stem}_angles.txt.gz",
        folder / _VICON_POSITIONS / f"{stem}_positions.txt.gz",
    )


def pair_repetitions(
    root: str | Path, repetitions: Sequence[RepetitionId], *, max_lag: int = 15
) -> tuple[list[PairedRepetition], SessionReport]:
    """Read and pair the repetitions of one session (see the module docstring)."""
    folder = _root_folder(Path(root))
    report = SessionReport(session=repetitions[0].session if repetitions else "")
    kinect: list[tuple[RepetitionId, Recording]] = []
    vicon: list[np.ndarray] = []
    widths: list[float] = []
    for rep in repetitions:
        kin_pos, kin_ang, vic = _files(folder, rep)
        if not vic.is_file():
            report.skipped[rep.name] = "no Vicon file"
            continue
        try:
            recording = read_kinect_repetition(kin_pos, kin_ang)
            markers, _ = read_vicon_markers(vic)
        except (DataFormatError, FileNotFoundError) as error:
            report.skipped[rep.name] = str(error)
            continue
        centres = vicon_joint_centres(markers)
        widths.append(float(np.median(pelvis_width(markers))))
        kinect.append((rep, recording))
        vicon.append(poses.resample(centres, VICON_FPS, KINECT_FPS))
    if not kinect:
        return [], report
    report.pelvis_width_m = width = float(np.median(widths))
    low, high = PLAUSIBLE_PELVIS_WIDTH_M
    if not low <= width <= high:
        report.warnings.append(
            f"{report.session}: the Vicon pelvis markers LASI-RASI are {1000 * width:.0f} mm "
            f"apart (expected {1000 * low:.0f}-{1000 * high:.0f} mm): the hip centres, so "
            "HipCenter and the ground truth's hip and spine bones, are suspect"
        )
    pairing = pair_session(
        [r.positions.astype(np.float64) for _, r in kinect], vicon, max_lag=max_lag
    )
    paired: list[PairedRepetition] = []
    for (rep, recording), reference, lag, distance in zip(
        kinect, vicon, pairing.lags, pairing.distances, strict=True
    ):
        reference = apply_rigid(reference, pairing.rotation, pairing.shift).astype(np.float32)
        start, stop = overlap(recording.num_frames, len(reference), lag)
        if stop - start < 2:
            report.skipped[rep.name] = "Kinect and Vicon do not overlap"
            continue
        cut = Recording(
            positions=recording.positions[start:stop],
            states=recording.states[start:stop],
            timestamps=recording.timestamps[start:stop] - recording.timestamps[start],
            ground_truth=reference[start + lag : stop + lag],
            metadata={
                **recording.metadata,
                "ground_truth": "vicon",
                "joint_centre_rule": JOINT_CENTRE_RULE,
                "lag_frames": lag,
                "first_kinect_frame": start,
                "session_alignment_m": round(pairing.mean_distance, 5),
            },
        )
        paired.append(PairedRepetition(rep, cut, reference, lag, distance))
        report.repetitions.append(rep.name)
        report.lags.append(lag)
        report.alignment_m.append(distance)
        report.frames.append(cut.num_frames)
    return paired, report


def _previous_import(out_dir: Path) -> set[str]:
    """Files an earlier import wrote in ``out_dir`` (relative paths, from its ``import.json``;
    empty without one).

    Raises
    ------
    OutputError
        ``import.json`` is there but is not an import summary (not this command's).
    """
    path = out_dir / "import.json"
    if not path.exists():
        return set()
    try:
        summary = read_json(path)
        names = [
            name
            for report in summary["session_reports"]
            for name in report["repetitions"]
            if isinstance(name, str)
        ]
    except (DataFormatError, FileNotFoundError, TypeError, KeyError):
        raise OutputError(
            f"--out {out_dir}: import.json is not an fpg-gym import-uiprmd summary; import "
            "writes only into a new folder or one it wrote: choose another --out"
        ) from None
    return {f"{sub}/{name}.npz" for name in names for sub in ("recordings", "clips")}


def _check_out(out_dir: Path, names: Iterable[str]) -> None:
    """Refuse, before any work, to overwrite a file in ``out_dir`` that no earlier import
    wrote (a user's file under a repetition's name, or an unrelated ``import.json``)."""
    ours = _previous_import(out_dir)
    for name in names:
        for sub in ("recordings", "clips"):
            relative = f"{sub}/{name}.npz"
            target = out_dir / relative
            if (target.exists() or target.is_symlink()) and relative not in ours:
                raise OutputError(
                    f"--out {out_dir}: {relative} is there and no earlier import-uiprmd wrote it "
                    "(not in import.json); refusing to overwrite it: move it away, or choose "
                    "another --out"
                )


def _import_session(
    args: tuple[str, list[RepetitionId], str, int],
) -> dict[str, Any]:
    root, reps, out, max_lag = args
    out_dir = Path(out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        paired, report = pair_repetitions(root, reps, max_lag=max_lag)
    for pair in paired:
        name = pair.repetition.name
        # Both writers write beside the target and rename: never a half-written file.
        write_recording(out_dir / "recordings" / f"{name}.npz", pair.recording)
        clip = Clip(
            name=name,
            positions=pair.reference,
            fps=KINECT_FPS,
            source=str(_files(_root_folder(Path(root)), pair.repetition)[2]),
            metadata={"format": "ui-prmd-vicon", "joint_centre_rule": JOINT_CENTRE_RULE},
        )
        write_positions(out_dir / "clips" / f"{name}.npz", clip)
    return report.as_dict()


def flag_alignment_outliers(reports: Sequence[dict[str, Any]]) -> list[str]:
    """Mark the sessions whose mean alignment error is an outlier; return their warnings.

    Each report (:meth:`SessionReport.as_dict`) with a ``mean_alignment_m`` gets
    ``alignment_z`` (its robust z-score against the reports', None with fewer than
    :data:`MIN_SESSIONS_COMPARED`) and ``alignment_outlier``: a z-score above
    :data:`ALIGNMENT_OUTLIER_Z` or an error above :data:`MAX_ALIGNMENT_M`. An outlier's
    warning is appended to its ``warnings`` and returned.
    """
    scored = [r for r in reports if r.get("mean_alignment_m") is not None]
    errors = np.array([r["mean_alignment_m"] for r in scored], dtype=np.float64)
    compared = len(scored) >= MIN_SESSIONS_COMPARED
    scores = robust_z_scores(errors) if compared else np.full(len(scored), np.nan)
    median = float(np.median(errors)) if len(errors) else 0.0
    found: list[str] = []
    for report, error, z in zip(scored, errors, scores, strict=True):
        report["alignment_z"] = round(float(z), 2) if compared else None
        outlier = bool((compared and z > ALIGNMENT_OUTLIER_Z) or error > MAX_ALIGNMENT_M)
        report["alignment_outlier"] = outlier
        if not outlier:
            continue
        why = (
            f"a robust z-score of {z:.1f} against the {len(scored)} sessions' median of "
            f"{1000 * median:.0f} mm (above {ALIGNMENT_OUTLIER_Z})"
            if compared and z > ALIGNMENT_OUTLIER_Z
            else f"above {1000 * MAX_ALIGNMENT_M:.0f} mm"
        )
        warning = (
            f"{report['session']}: Kinect and Vicon joints {1000 * error:.0f} mm apart after "
            f"alignment, {why}: a marker, a joint centre or the Kinect's tracking is suspect"
        )
        report.setdefault("warnings", []).append(warning)
        found.append(warning)
    return found


def import_uiprmd(
    root: str | Path,
    out: str | Path,
    *,
    subjects: Iterable[str] | None = None,
    max_lag: int = 15,
    workers: int | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Import UI-PRMD repetitions into ``out`` (see the module docstring); returns the report.

    Parameters
    ----------
    root : str or Path
        The UI-PRMD folder (holding ``Kinect/`` and ``Vicon/``, or ``Segmented Movements``).
    out : str or Path
        Output folder; created. It must not lie inside ``root``.
    subjects : iterable of str, optional
        ``sNN`` names; all subjects found by default.
    max_lag : int
        Largest lag searched, in Kinect frames.
    workers : int, optional
        Processes (``os.cpu_count()``); 1 runs in this process.
    progress : bool
        Show a progress bar on stderr.
    """

    folder = _root_folder(Path(root)).resolve()
    out_dir = Path(out)
    resolved = out_dir.resolve()
    if resolved == folder or folder in resolved.parents or resolved in folder.parents:
        raise ValueError(f"--out: {out_dir} must not contain or lie inside the input {folder}")
    sessions = find_repetitions(folder, subjects)
    _check_out(out_dir, (rep.name for reps in sessions.values() for rep in reps))
    for sub in ("recordings", "clips"):
        try:
            (out_dir / sub).mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise OutputError(f"--out {out_dir / sub}: cannot create ({error.strerror})") from None
    tasks = [(str(folder), reps, str(out_dir), max_lag) for reps in sessions.values()]
    workers = workers or os.cpu_count() or 1
    reports: list[dict[str, Any]] = []
    bar = tqdm(total=len(tasks), desc="importing UI-PRMD", unit="session", disable=not progress)
    try:
        if workers <= 1:
            for task in tasks:
                reports.append(_import_session(task))
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                for report in pool.map(_import_session, tasks):
                    reports.append(report)
                    bar.update()
    finally:
        bar.close()
    flag_alignment_outliers(reports)
    alignment = [v for r in reports for v in r["alignment_m"]]
    lags = [v for r in reports for v in r["lags"]]
    summary = {
        "root": str(folder),
        "out": str(out_dir),
        "joint_centre_rule": JOINT_CENTRE_RULE,
        "sessions": len(reports),
        "repetitions": len(alignment),
        "skipped": {k: v for r in reports for k, v in r["skipped"].items()},
        "warnings": [w for r in reports for w in r["warnings"]],
        "alignment_outliers": [r["session"] for r in reports if r.get("alignment_outlier")],
        "mean_alignment_m": round(float(np.mean(alignment)), 5) if alignment else None,
        "median_lag_frames": float(np.median(lags)) if lags else None,
        "session_reports": reports,
    }
    write_text(out_dir / "import.json", json.dumps(summary, indent=1))
    return summary
