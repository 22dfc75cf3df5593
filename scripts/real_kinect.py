"""The real-data benchmark: UI-PRMD Kinect v2 streams against Vicon, with and without occlusion.

For every held-out subject (a fold), everything fitted or built from data sees only the *other*
subjects: the UI-PRMD database (their Vicon joint centres), the Kinect v2 -> Vicon map, the
Kinect v2 bone model and the reference poses that fit a foreign database's definitions. The
held-out subject's repetitions (``--reps`` per exercise, the middle ones) are reconstructed as
they are (``none``) and with each occlusion case of :mod:`fpg_gym.simulate.occlude` put into
them (``--occlusions``), and scored against Vicon (:mod:`fpg_gym.io.ui_prmd` gives the
joint-centre rule).

Databases (``--databases``): ``uiprmd`` (a Filtered Pose Graph of the training subjects' Vicon
joint centres, thres1 ``--uiprmd-thres1``), ``embedded`` (the DeepMimic clips), ``bandai``
(Bandai Namco ``dataset-1``, thres1 0.2 m, mirrored; built once into ``--work``).

Methods: the baselines a Kinect user already has (``raw``, ``holt``, ``one-euro`` and the same
through the fold's Kinect v2 -> Vicon map: ``raw+map``, ``holt+map``, ``one-euro+map``), the
reconstruction with the ``auto`` preset fed with the fold's resources
(:func:`fpg_gym.reconstruct.presets.pipeline`: what ``fpg-gym reconstruct`` does with no tuning
flag on a Kinect v2 recording), and ``papers:`` rows with the papers' pipeline.

Columns: FPG Eq. 13, MPJPE (absolute), root-relative and Procrustes-aligned MPJPE, the MPJPE of
occluded and of visible joints, jitter, lag, bone-length error against the truth, the settled
bone spread and the worst joint (MPJPE ratio to raw). One table per database and occlusion
case, then every case pooled.

Usage::

    python scripts/real_kinect.py                      # 8 folds, 1 repetition per exercise
    python scripts/real_kinect.py --subjects s01,s02 --databases uiprmd --occlusions none,legs
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import metrics, skeleton
from fpg_gym.definitions import DefinitionMap, fit_sensor_maps
from fpg_gym.graph import FilteredPoseGraph, default_graph
from fpg_gym.io import load_clips
from fpg_gym.io.positions import read_positions
from fpg_gym.io.recording import Recording, load_recording
from fpg_gym.io.ui_prmd_import import import_uiprmd
from fpg_gym.methods import MethodRunner
from fpg_gym.reconstruct import ENERGY_DTYPES, ReconstructorConfig
from fpg_gym.reconstruct.bone_model import LinearBoneModel
from fpg_gym.reconstruct.presets import SensorResources, pipeline
from fpg_gym.simulate import episode_seed
from fpg_gym.simulate.occlude import OCCLUSION_CASES, occlude

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data"
BASELINES = ("raw", "holt", "one-euro", "raw+map", "holt+map", "one-euro+map")
DEFAULT_METHODS = ("fpg:closed-form", "fpg:local-search", "papers:fpg:local-search")
#: The baseline every ratio below "x map+holt" refers to.
MAPPED_HOLT = "holt+map"


def imported_uiprmd(work: Path, data: Path) -> Path:
    """The UI-PRMD import under ``work`` (``work/ui_prmd``), made from ``data/ui_prmd`` the
    first time."""
    out = work / "ui_prmd"
    if not (out / "import.json").is_file():
        print(f"importing UI-PRMD into {out} ...", file=sys.stderr)
        import_uiprmd(data / "ui_prmd", out, progress=True)
    return out


def by_subject(folder: Path) -> dict[str, list[Path]]:
    """The imported recordings ``m*_s*_e*.npz`` of ``folder`` by subject (``s01`` ...)."""
    groups: dict[str, list[Path]] = defaultdict(list)
    for path in sorted(folder.glob("m*_s*_e*.npz")):
        groups[path.stem.split("_")[1]].append(path)
    return dict(groups)


def repetitions(paths: list[Path], reps: int) -> list[Path]:
    """``reps`` repetitions per exercise, from the middle of the session (first ones are
    often badly segmented); every one of ``paths``, in their order, when ``reps`` is 0."""
    if reps <= 0:
        return list(paths)
    by_movement: dict[str, list[Path]] = defaultdict(list)
    for path in paths:
        by_movement[path.stem.split("_")[0]].append(path)
    chosen = []
    for movement in sorted(by_movement):
        items = by_movement[movement]
        middle = len(items) // 2
        chosen.extend(items[max(0, middle - reps // 2) : max(0, middle - reps // 2) + reps])
    return chosen


def uiprmd_graph(
    imported: Path, exclude: set[str], thres1: float, movement: str | None = None
) -> FilteredPoseGraph:
    """The UI-PRMD database: a graph of the Vicon joint centres of every subject but
    ``exclude`` (``imported`` is an ``import-uiprmd`` folder), without ``movement``'s clips
    when given."""
    clips = [
        read_positions(p)
        for p in sorted((imported / "clips").glob("*.npz"))
        if p.stem.split("_")[1] not in exclude and p.stem.split("_")[0] != movement
    ]
    return FilteredPoseGraph.build(clips, thres1=thres1, progress=False)


def _bandai_graph(work: Path, data: Path) -> FilteredPoseGraph:
    path = work / "bandai-dataset1.npz"
    if not path.is_file():
        clips = load_clips([data / "bandai_namco" / "dataset-1"], progress=True)
        FilteredPoseGraph.build(clips, thres1=0.2, mirror=True, progress=True).save(path)
    return FilteredPoseGraph.load(path)


def fold_maps(
    database: str,
    graph: FilteredPoseGraph,
    train: list[Recording],
    use_maps: bool,
    database_maps: bool,
) -> tuple[DefinitionMap | None, Any, dict[str, Any]]:
    """Sensor map and output map of one fold (None when not used)."""
    if not use_maps:
        return None, None, {}
    sensor = np.concatenate([r.positions for r in train])
    truth = np.concatenate([r.ground_truth for r in train if r.ground_truth is not None])
    if database == "uiprmd" or not database_maps:
        sensor_map, _ = fit_sensor_maps(sensor, truth, sensor="kinect-v2", truth="vicon")
        return sensor_map, None, {"sensor_map": sensor_map.info}
    sensor_map, output_map = fit_sensor_maps(
        sensor,
        truth,
        sensor="kinect-v2",
        truth="vicon",
        database=graph.poses,
        database_name=database,
    )
    return sensor_map, output_map, {"sensor_map": sensor_map.info}


def fold_resources(
    train: list[Recording],
    imported: Path,
    held_out: str,
    thres1: float,
    movement: str | None = None,
) -> tuple[SensorResources, FilteredPoseGraph]:
    """The Kinect v2 resources fitted without ``held_out`` (map, bone model, reference poses)
    and the UI-PRMD database of the other subjects; without ``movement`` (``m01``...) too when
    given (a person and a movement never seen)."""
    if movement is not None:
        train = [r for r in train if not str(r.metadata["repetition"]).startswith(movement)]
    sensor = np.concatenate([r.positions for r in train])
    truth = np.concatenate([r.ground_truth for r in train if r.ground_truth is not None])
    groups = np.concatenate([[r.metadata["subject"]] * r.num_frames for r in train])
    to_vicon = DefinitionMap.fit(sensor, truth, source="kinect-v2", target="vicon")
    bones = LinearBoneModel.fit(to_vicon.apply(sensor), truth, groups, source="k2", target="v")
    graph = uiprmd_graph(imported, {held_out}, thres1, movement)
    graph.params["definitions"] = "vicon"
    return SensorResources(to_vicon, bones, graph.poses), graph


def _scores(recording: Recording, poses: np.ndarray) -> dict[str, Any]:
    truth = recording.ground_truth
    assert truth is not None
    occluded = recording.occluded
    if occluded is None:
        occluded = np.zeros(recording.states.shape, dtype=bool)
    distances = metrics.joint_distances(truth, poses)
    spread = metrics.settled_bone_spread(poses, timestamps=recording.timestamps)
    return {
        "frames": int(recording.num_frames),
        "eq13_m": metrics.mean_error(truth, poses),
        "mpjpe_m": float(distances.mean()),
        "root_mpjpe_m": metrics.mpjpe(truth, poses, "root"),
        "pa_mpjpe_m": metrics.mpjpe(truth, poses, "procrustes"),
        "occluded_m": float(distances[occluded].mean()) if occluded.any() else float("nan"),
        "occluded_sum_m": float(distances[occluded].sum()),
        "occluded_count": int(occluded.sum()),
        "visible_m": float(distances[~occluded].mean()),
        "per_joint_m": distances.mean(axis=0).tolist(),
        "jitter": float(np.nanmean(metrics.jitter(poses, fps=recording.fps))),
        "lag_frames": metrics.lag(poses, truth),
        "bone_length_error_mm": 1000.0 * float(metrics.bone_length_error(truth, poses).mean()),
        "bone_spread_mm": (
            float(1000.0 * np.nanmax(spread)) if np.isfinite(spread).any() else float("nan")
        ),
    }


def _run_fold(task: dict[str, Any]) -> dict[str, Any]:
    """One held-out subject with one database: every method on every episode and case."""
    work, data = Path(task["work"]), Path(task["data"])
    imported = Path(task["imported"])
    subjects = by_subject(imported / "recordings")
    held_out = task["subject"]
    train = [load_recording(p) for s, ps in subjects.items() if s != held_out for p in ps]
    t0 = time.process_time()
    database = task["database"]
    setups: dict[str | None, tuple[Any, dict[str, MethodRunner]]] = {}

    def setup(movement: str | None) -> tuple[Any, dict[str, MethodRunner]]:
        """The fold's resources, database and runners (without ``movement`` when given)."""
        if movement not in setups:
            resources, uiprmd = fold_resources(
                train, imported, held_out, task["uiprmd_thres1"], movement
            )
            if database == "uiprmd":
                graph = uiprmd
            elif database == "embedded":
                graph = default_graph()
            else:
                graph = _bandai_graph(work, data)
            chosen = {
                "auto": pipeline("auto", "kinect-v2", graph, resources=resources),
                "papers": pipeline("papers", "kinect-v2", graph),
            }
            runners = {
                name: MethodRunner(
                    graph,
                    budget=task["budget"],
                    reconstructor_options={**p.options, "energy_dtype": task["energy_dtype"]},
                )
                for name, p in chosen.items()
            }
            setups[movement] = ((resources, graph, chosen), runners)
        return setups[movement]

    (resources, graph, chosen), _ = setup(None)
    setup_s = time.process_time() - t0
    rows = []
    for path in repetitions(subjects[held_out], task["reps"]):
        movement = path.stem.split("_")[0] if task["leave_exercise_out"] else None
        runners = setup(movement)[1]
        clean = load_recording(path)
        for case in task["occlusions"]:
            recording = (
                clean
                if case == "none"
                else occlude(clean, case, episode_seed(task["seed"], path.stem, case))
            )
            for method in [*BASELINES, *task["methods"]]:
                preset, name = "auto", method
                if method.startswith("papers:"):
                    preset, name = "papers", method.removeprefix("papers:")
                c0 = time.process_time()
                result = runners[preset].run(name, recording, seed=task["seed"])
                cpu = 1000 * (time.process_time() - c0) / recording.num_frames
                rows.append(
                    {
                        "database": database,
                        "subject": held_out,
                        "episode": path.stem,
                        "case": case,
                        "method": method,
                        "cpu_ms_per_frame": cpu,
                        **_scores(recording, result.poses),
                    }
                )
    for _, fold_runners in setups.values():
        for runner in fold_runners.values():
            runner.close()
    return {
        "database": database,
        "subject": held_out,
        "nodes": len(graph.poses),
        "setup_cpu_s": setup_s,
        "bone_model": resources.bone_model.info if resources.bone_model else None,
        "pipelines": {name: p.summary() for name, p in chosen.items()},
        "rows": rows,
    }


def _mean(rows: list[dict[str, Any]], key: str) -> float:
    values = [r[key] for r in rows if np.isfinite(r[key])]
    return float(np.mean(values)) if values else float("nan")


def _pooled_occluded(rows: list[dict[str, Any]]) -> float:
    count = sum(r["occluded_count"] for r in rows)
    return sum(r["occluded_sum_m"] for r in rows) / count if count else float("nan")


def table(rows: list[dict[str, Any]], title: str) -> str:
    """One markdown table of ``rows`` (one database; one case or several pooled)."""
    by_method: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        by_method[row["method"]].append(row)
    raw, holt = by_method["raw"], by_method[MAPPED_HOLT]
    raw_keyed = {(r["episode"], r["case"]): r for r in raw}
    raw_joint = np.mean([r["per_joint_m"] for r in raw], axis=0)
    raw_occluded = _pooled_occluded(raw)
    lines = [
        f"#### {title} ({len(raw)} episodes)",
        "",
        "| method | Eq. 13 (m) | × raw | MPJPE (m) | × raw | × map+Holt | better than raw "
        "| root-rel. | PA | occluded (m) | × raw | visible × map+Holt | jitter × raw "
        "| lag (frames) | bone length err. (mm) | bone spread (mm) | worst joint × raw |",
        "| --- " * 17 + "|",
    ]
    for method, rs in by_method.items():
        mpjpe, eq13 = _mean(rs, "mpjpe_m"), _mean(rs, "eq13_m")
        occluded = _pooled_occluded(rs)
        better = sum(r["mpjpe_m"] < raw_keyed[(r["episode"], r["case"])]["mpjpe_m"] for r in rs)
        ratio = np.mean([r["per_joint_m"] for r in rs], axis=0) / raw_joint
        worst = int(np.nanargmax(ratio))
        lines.append(
            f"| {method} | {eq13:.4f} | {eq13 / _mean(raw, 'eq13_m'):.2f} | {mpjpe:.4f} | "
            f"{mpjpe / _mean(raw, 'mpjpe_m'):.2f} | {mpjpe / _mean(holt, 'mpjpe_m'):.2f} | "
            f"{better}/{len(rs)} | {_mean(rs, 'root_mpjpe_m'):.4f} | {_mean(rs, 'pa_mpjpe_m'):.4f} "
            f"| {occluded:.3f} | {occluded / raw_occluded:.2f} | "
            f"{_mean(rs, 'visible_m') / _mean(holt, 'visible_m'):.2f} | "
            f"{_mean(rs, 'jitter') / _mean(raw, 'jitter'):.2f} | {_mean(rs, 'lag_frames'):.2f} | "
            f"{_mean(rs, 'bone_length_error_mm'):.1f} | "
            f"{np.nanmax([r['bone_spread_mm'] for r in rs]):.1f} | "
            f"{ratio[worst]:.2f} ({skeleton.JOINT_NAMES[worst]}) |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="shared data folder")
    parser.add_argument("--work", type=Path, default=Path("runs/real_kinect"), help="work folder")
    parser.add_argument("--subjects", default="s01,s02,s03,s04,s05,s06,s07,s08")
    parser.add_argument("--databases", default="uiprmd,embedded,bandai")
    parser.add_argument("--occlusions", default="none," + ",".join(OCCLUSION_CASES))
    parser.add_argument("--methods", default=",".join(DEFAULT_METHODS))
    parser.add_argument("--reps", type=int, default=1, help="repetitions per exercise scored")
    parser.add_argument("--budget", type=int, default=2000, help="evaluations per frame")
    parser.add_argument("--uiprmd-thres1", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0, help="occlusions' and optimisers' seed")
    parser.add_argument(
        "--leave-exercise-out",
        action="store_true",
        help="fit the map, the bone model and the UI-PRMD database without the scored "
        "episode's exercise too (a person and a movement never seen)",
    )
    parser.add_argument(
        "--energy-dtype",
        choices=ENERGY_DTYPES,
        default=ReconstructorConfig().energy_dtype,
        help="the energy's arithmetic (ReconstructorConfig.energy_dtype; default %(default)s)",
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write every row here")
    args = parser.parse_args(argv)
    if not (args.data / "ui_prmd").is_dir():
        print(f"no UI-PRMD data under {args.data}", file=sys.stderr)
        return 2
    occlusions = args.occlusions.split(",")
    unknown = sorted(set(occlusions) - {"none", *OCCLUSION_CASES})
    if unknown:
        print(f"--occlusions: unknown {unknown}; expected none or {list(OCCLUSION_CASES)}")
        return 2
    args.work.mkdir(parents=True, exist_ok=True)
    imported = imported_uiprmd(args.work, args.data)
    if "bandai" in args.databases:
        _bandai_graph(args.work, args.data)  # once, before the workers
    tasks = [
        {
            "work": str(args.work),
            "data": str(args.data),
            "imported": str(imported),
            "subject": subject,
            "database": database,
            "methods": args.methods.split(","),
            "occlusions": occlusions,
            "reps": args.reps,
            "budget": args.budget,
            "uiprmd_thres1": args.uiprmd_thres1,
            "seed": args.seed,
            "leave_exercise_out": args.leave_exercise_out,
            "energy_dtype": args.energy_dtype,
        }
        for database in args.databases.split(",")
        for subject in args.subjects.split(",")
    ]
    start_wall = time.perf_counter()
    results = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for result in pool.map(_run_fold, tasks):
            print(
                f"{result['database']:>9} held out {result['subject']}: {result['nodes']} nodes, "
                f"setup {result['setup_cpu_s']:.1f} s CPU",
                file=sys.stderr,
            )
            results.append(result)
    rows = [row for result in results for row in result["rows"]]
    print(
        f"UI-PRMD leave-subjects-out, subjects {args.subjects}, {args.reps} repetition(s) per "
        f"exercise, occlusions {args.occlusions}, seed {args.seed}"
        + (", exercises left out too" if args.leave_exercise_out else "")
        + f", energy {args.energy_dtype}; "
        f"wall {time.perf_counter() - start_wall:.0f} s\n"
    )
    for database in args.databases.split(","):
        mine = [r for r in rows if r["database"] == database]
        print(f"### database: {database}\n")
        for case in occlusions:
            print(table([r for r in mine if r["case"] == case], f"{database}, {case}") + "\n")
        occluded = [r for r in mine if r["case"] != "none"]
        if occluded:
            print(table(occluded, f"{database}, every occlusion case pooled") + "\n")
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "args": vars(args)
                    | {"data": str(args.data), "work": str(args.work), "json": str(args.json)},
                    "folds": results,
                },
                indent=1,
                default=str,
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
