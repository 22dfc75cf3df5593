"""The real-data protocol: UI-PRMD Kinect v2 streams scored against Vicon, leave subjects out.

For every held-out subject (a fold), everything fitted or built from data sees only the *other*
subjects: the UI-PRMD database (their Vicon joint centres), the sensor's definition map
(Kinect v2 -> Vicon joint centres, fitted on their paired repetitions) and the database maps.
The held-out subject's repetitions (``--reps`` per exercise) are then reconstructed by every
method with every database and scored with FPG Eq. 13 against Vicon (:mod:`fpg_gym.io.ui_prmd`
gives the joint-centre rule).

Databases (``--databases``):

``uiprmd``
    A Filtered Pose Graph of the training subjects' Vicon joint centres (``--uiprmd-thres1``).
    Sensor map: Kinect v2 -> Vicon, fitted on the training pairs; no output map.
``embedded``
    The embedded DeepMimic graph (:func:`fpg_gym.graph.default_graph`).
``bandai``
    A graph of Bandai Namco ``dataset-1`` (thres1 0.2 m, mirrored), built once into ``--work``.

For ``embedded`` and ``bandai`` the database's own joint definitions are found by
:func:`fpg_gym.definitions.fit_to_database` (Vicon joint centres of the training subjects ->
the database's definitions, by alternating nearest-pose matching and least squares); the sensor
map is Kinect v2 -> that, fitted on the training pairs, and the output map is its inverse back
to Vicon joint centres. ``--no-maps`` runs without any map (the papers' pipeline as it was).

Rows: ``raw`` (the sensor), ``raw+map`` (the sensor through the fitted Kinect v2 -> Vicon map,
a definition-corrected sensor baseline that needs no database), ``holt``, ``kalman``, and the
reconstruction methods (``+ragdoll``: through the pybullet PD ragdoll). Columns: mean Eq. 13
error, its ratio to raw, episodes better than raw, Err0.2, jitter, the worst joint's ratio to raw.

Usage::

    python scripts/real_kinect.py                          # 8 folds, 1 repetition per exercise
    python scripts/real_kinect.py --subjects s01,s02 --databases uiprmd --reps 2
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

from fpg_gym import metrics, skeleton
from fpg_gym.definitions import DefinitionMap, fit_sensor_maps
from fpg_gym.graph import FilteredPoseGraph, default_graph
from fpg_gym.io import load_clips
from fpg_gym.io.positions import read_positions
from fpg_gym.io.recording import Recording, load_recording
from fpg_gym.io.ui_prmd_import import import_uiprmd
from fpg_gym.methods import MethodRunner

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data"
DEFAULT_METHODS = (
    "raw",
    "holt",
    "kalman",
    "fpg:local-search",
    "fpg:closed-form",
    "shum:local-search",
    "fpg:local-search+ragdoll",
)


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


def uiprmd_graph(imported: Path, exclude: set[str], thres1: float) -> FilteredPoseGraph:
    """The UI-PRMD database: a graph of the Vicon joint centres of every subject but
    ``exclude`` (``imported`` is an ``import-uiprmd`` folder)."""
    clips = [
        read_positions(p)
        for p in sorted((imported / "clips").glob("*.npz"))
        if p.stem.split("_")[1] not in exclude
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


def _run_fold(task: dict[str, Any]) -> dict[str, Any]:
    """One held-out subject with one database: every method on every chosen episode."""
    work, data = Path(task["work"]), Path(task["data"])
    imported = Path(task["imported"])
    subjects = by_subject(imported / "recordings")
    held_out = task["subject"]
    train = [load_recording(p) for s, ps in subjects.items() if s != held_out for p in ps]
    database = task["database"]
    t0 = time.process_time()
    if database == "uiprmd":
        graph = uiprmd_graph(imported, {held_out}, task["uiprmd_thres1"])
    elif database == "embedded":
        graph = default_graph()
    else:
        graph = _bandai_graph(work, data)
    sensor_map, output_map, map_info = fold_maps(
        database, graph, train, task["maps"], task["database_maps"]
    )
    kinect_to_vicon = DefinitionMap.fit(
        np.concatenate([r.positions for r in train]),
        np.concatenate([r.ground_truth for r in train if r.ground_truth is not None]),
        source="kinect-v2",
        target="vicon",
    )
    setup_s = time.process_time() - t0
    options: dict[str, Any] = {
        "sensor_map": sensor_map,
        "output_map": output_map,
        "sensor_blend": task["blend"],
    }
    if task["calibrate"]:  # the output map fitted online from the stream's tracked joints
        options.update(output_map=None, calibrate_output=True, calibration_map=kinect_to_vicon)
    if task.get("temporal") == "off":  # the papers' pipeline (issue 15's switches off)
        from fpg_gym.reconstruct import BoneSettlingConfig, TemporalConfig

        options["temporal"] = TemporalConfig.off()
        options["bones"] = BoneSettlingConfig(enabled=False)
    elif task.get("temporal") == "no-placement":  # the defaults without placement smoothing
        from fpg_gym.reconstruct import TemporalConfig

        options["temporal"] = TemporalConfig(placement=False)
    rows = []
    with MethodRunner(graph, budget=task["budget"], reconstructor_options=options) as runner:
        for path in repetitions(subjects[held_out], task["reps"]):
            recording = load_recording(path)
            truth = recording.ground_truth
            assert truth is not None
            outputs = {"raw+map": kinect_to_vicon.apply(recording.positions)}
            cpu: dict[str, float] = {"raw+map": 0.0}
            for method in task["methods"]:
                c0 = time.process_time()
                outputs[method] = runner.run(method, recording, seed=0).poses
                cpu[method] = 1000 * (time.process_time() - c0) / recording.num_frames
            for method, poses in outputs.items():
                errors = metrics.frame_error(truth, poses)
                spread = metrics.settled_bone_spread(poses, timestamps=recording.timestamps)
                rows.append(
                    {
                        "database": database,
                        "subject": held_out,
                        "episode": path.stem,
                        "method": method,
                        "frames": int(recording.num_frames),
                        "mean_error_m": float(errors.mean()),
                        "err02": float(metrics.err_ratio(errors)),
                        "per_joint_m": metrics.per_joint_error(truth, poses).tolist(),
                        "jitter": float(np.nanmean(metrics.jitter(poses, fps=recording.fps))),
                        "lag_frames": metrics.lag(poses, truth),
                        "bone_spread_mm": (
                            float(1000.0 * np.nanmax(spread))
                            if np.isfinite(spread).any()
                            else float("nan")
                        ),
                        "cpu_ms_per_frame": cpu[method],
                    }
                )
    return {
        "database": database,
        "subject": held_out,
        "nodes": len(graph.poses),
        "setup_cpu_s": setup_s,
        "maps": map_info,
        "rows": rows,
    }


def _table(rows: list[dict[str, Any]], database: str) -> str:
    mine = [r for r in rows if r["database"] == database]
    raw = {r["episode"]: r for r in mine if r["method"] == "raw"}
    methods = list(dict.fromkeys(r["method"] for r in mine))
    lines = [
        f"### database: {database} ({len(raw)} episodes, "
        f"{len({r['subject'] for r in mine})} held-out subjects)",
        "",
        "| method | mean error (m) | × raw | better than raw | Err0.2 (%) | worst joint × raw "
        "| jitter (m/s²) | × raw jitter | lag (frames) | bone spread after 1 s, max (mm) "
        "| CPU ms/frame |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    raw_error = np.mean([r["mean_error_m"] for r in raw.values()])
    raw_joint = np.mean([r["per_joint_m"] for r in raw.values()], axis=0)
    raw_jitter = np.mean([r["jitter"] for r in raw.values()])
    for method in methods:
        rs = [r for r in mine if r["method"] == method]
        error = np.mean([r["mean_error_m"] for r in rs])
        better = sum(r["mean_error_m"] < raw[r["episode"]]["mean_error_m"] for r in rs)
        joint = np.mean([r["per_joint_m"] for r in rs], axis=0)
        ratio = joint / raw_joint
        worst = int(np.nanargmax(ratio))
        jitter = np.mean([r["jitter"] for r in rs])
        lag = np.nanmean([r.get("lag_frames", np.nan) for r in rs])
        spread = np.nanmax([r.get("bone_spread_mm", np.nan) for r in rs])
        lines.append(
            f"| {method} | {error:.4f} | {error / raw_error:.2f} | {better}/{len(rs)} | "
            f"{100 * np.mean([r['err02'] for r in rs]):.1f} | "
            f"{ratio[worst]:.2f} ({skeleton.JOINT_NAMES[worst]}) | {jitter:.1f} | "
            f"{jitter / raw_jitter:.1f} | {lag:.2f} | {spread:.1f} | "
            f"{np.median([r['cpu_ms_per_frame'] for r in rs]):.2f} |"
        )
    return "\n".join(lines)


def _joint_table(rows: list[dict[str, Any]], database: str, methods: list[str]) -> str:
    mine = [r for r in rows if r["database"] == database]
    header = "| joint | " + " | ".join(methods) + " |"
    lines = [header, "| --- " * (len(methods) + 1) + "|"]
    per = {
        m: np.mean([r["per_joint_m"] for r in mine if r["method"] == m], axis=0) for m in methods
    }
    for j in range(1, skeleton.NUM_JOINTS):
        cells = " | ".join(f"{100 * per[m][j]:.1f}" for m in methods)
        lines.append(f"| {skeleton.JOINT_NAMES[j]} | {cells} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="shared data folder")
    parser.add_argument("--work", type=Path, default=Path("runs/real_kinect"), help="work folder")
    parser.add_argument("--subjects", default="s01,s02,s03,s04,s05,s06,s07,s08")
    parser.add_argument("--databases", default="uiprmd,embedded,bandai")
    parser.add_argument("--methods", default=",".join(DEFAULT_METHODS))
    parser.add_argument("--reps", type=int, default=1, help="repetitions per exercise scored")
    parser.add_argument("--budget", type=int, default=2000, help="evaluations per frame")
    parser.add_argument("--uiprmd-thres1", type=float, default=0.1)
    parser.add_argument("--no-maps", action="store_true", help="run without definition maps")
    parser.add_argument("--sensor-blend", type=float, default=0.0)
    parser.add_argument(
        "--no-database-maps",
        action="store_true",
        help="map the sensor to Vicon joint centres and take the database's as the same",
    )
    parser.add_argument(
        "--temporal",
        choices=("default", "off", "no-placement"),
        default="default",
        help="issue 15's temporal switches and bone settling: defaults, off (the papers'), or "
        "the defaults without placement smoothing",
    )
    parser.add_argument(
        "--calibrate-output",
        action="store_true",
        help="fit the output's definitions online from each stream's tracked joints (to the "
        "sensor mapped to Vicon) instead of the database-fitted output map",
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write every row here")
    args = parser.parse_args(argv)
    if not (args.data / "ui_prmd").is_dir():
        print(f"no UI-PRMD data under {args.data}", file=sys.stderr)
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
            "reps": args.reps,
            "budget": args.budget,
            "uiprmd_thres1": args.uiprmd_thres1,
            "maps": not args.no_maps,
            "blend": args.sensor_blend,
            "database_maps": not args.no_database_maps,
            "temporal": args.temporal,
            "calibrate": args.calibrate_output,
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
                f"maps {json.dumps(result['maps'])}",
                file=sys.stderr,
            )
            results.append(result)
    rows = [row for result in results for row in result["rows"]]
    print(
        f"UI-PRMD leave-subjects-out, subjects {args.subjects}, {args.reps} repetition(s) per "
        f"exercise, maps {'off' if args.no_maps else 'on'}, sensor blend {args.sensor_blend}, "
        f"temporal {args.temporal}, output calibration {'on' if args.calibrate_output else 'off'}; "
        f"wall {time.perf_counter() - start_wall:.0f} s\n"
    )
    for database in args.databases.split(","):
        print(_table(rows, database) + "\n")
        methods = ["raw", "raw+map", *[m for m in args.methods.split(",") if m != "raw"]]
        print(_joint_table(rows, database, methods) + "\n")
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "args": vars(args)
                    | {"data": str(args.data), "work": str(args.work), "json": str(args.json)},
                    "folds": results,
                },
                indent=1,
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
