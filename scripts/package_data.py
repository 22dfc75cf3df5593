"""Rebuild the Kinect v2 data shipped in ``fpg_gym/data`` from UI-PRMD's shared subjects.

Writes, from seven subjects of ``../shared/data/ui_prmd`` (s01-s07; s08 is kept out of every
packaged model so that the demo can score its repetitions, and UI-PRMD's own s09 and s10 are
never used):

* ``kinect-v2-to-vicon.json``: the Kinect v2 -> Vicon joint-centre definition map
  (:meth:`fpg_gym.definitions.DefinitionMap.fit` on every paired frame);
* ``kinect-v2-to-vicon-bones.npz``: the bone model of the mapped sensor
  (:class:`fpg_gym.reconstruct.bone_model.LinearBoneModel`, penalty by leave-one-subject-out);
* ``uiprmd-graph.npz``: the Filtered Pose Graph of the Vicon joint centres (thres1 0.1 m),
  marked ``params["definitions"] = "vicon"``;
* ``kinect-v2-to-embedded.json`` and ``kinect-v2-to-bandai.json``: Kinect v2 -> the embedded
  and the Bandai Namco ``dataset-1`` databases' definitions
  (:func:`fpg_gym.definitions.fit_sensor_maps`);
* ``demo/*.npz``: four repetitions of s08 (the middle one of a squat, a hurdle step, a sit to
  stand and a shoulder abduction) with their Vicon joint centres, for ``fpg-gym demo``.

Usage::

    python scripts/package_data.py                  # import into runs/package, write fpg_gym/data
    python scripts/package_data.py --out /tmp/check # write elsewhere to compare
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from fpg_gym.definitions import DefinitionMap, fit_sensor_maps
from fpg_gym.graph import FilteredPoseGraph, default_graph
from fpg_gym.io import load_clips
from fpg_gym.io.positions import read_positions
from fpg_gym.io.recording import Recording, load_recording, write_recording
from fpg_gym.io.ui_prmd_import import import_uiprmd
from fpg_gym.reconstruct.bone_model import LinearBoneModel

REPO = Path(__file__).resolve().parents[1]
SUBJECTS = ("s01", "s02", "s03", "s04", "s05", "s06", "s07")
#: The demo's subject and repetitions (never in a packaged model).
DEMO_SUBJECT = "s08"
DEMO_REPETITIONS = ("m01_s08_e05", "m02_s08_e05", "m05_s08_e05", "m07_s08_e05")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    parser.add_argument("--work", type=Path, default=Path("runs/package"))
    parser.add_argument("--out", type=Path, default=REPO / "fpg_gym" / "data")
    args = parser.parse_args(argv)
    imported = args.work / "ui_prmd"
    if not (imported / "import.json").is_file():
        subjects = [*SUBJECTS, DEMO_SUBJECT]
        import_uiprmd(args.data / "ui_prmd", imported, subjects=subjects, progress=True)
    recordings = [
        load_recording(p)
        for p in sorted((imported / "recordings").glob("m*_s*_e*.npz"))
        if p.stem.split("_")[1] in SUBJECTS
    ]
    sensor = np.concatenate([r.positions for r in recordings])
    truth = np.concatenate([r.ground_truth for r in recordings if r.ground_truth is not None])
    groups = np.concatenate([[r.metadata["subject"]] * r.num_frames for r in recordings])
    args.out.mkdir(parents=True, exist_ok=True)

    (args.out / "demo").mkdir(exist_ok=True)
    for name in DEMO_REPETITIONS:
        demo = load_recording(imported / "recordings" / f"{name}.npz")
        metadata = {k: v for k, v in demo.metadata.items() if k != "source"}
        write_recording(
            args.out / "demo" / f"{name}.npz",
            Recording(
                demo.positions,
                demo.states,
                demo.timestamps,
                demo.ground_truth,
                {**metadata, "source": f"UI-PRMD {name} (Vakanski et al. 2018, ODC-PDDL)"},
            ),
        )
    to_vicon = DefinitionMap.fit(sensor, truth, source="kinect-v2", target="vicon")
    to_vicon.info["recordings"] = len(recordings)
    to_vicon.save(args.out / "kinect-v2-to-vicon.json")
    bones = LinearBoneModel.fit(
        to_vicon.apply(sensor), truth, groups, source="kinect-v2 (mapped)", target="vicon"
    )
    bones.info["recordings"] = len(recordings)
    bones.save(args.out / "kinect-v2-to-vicon-bones.npz")
    print(f"{to_vicon!r}; {bones!r}: cross-validation {bones.info['cross_validation_m']}")

    clips = [
        read_positions(p)
        for p in sorted((imported / "clips").glob("*.npz"))
        if p.stem.split("_")[1] in SUBJECTS
    ]
    graph = FilteredPoseGraph.build(clips, thres1=0.1, progress=True)
    graph.params["definitions"] = "vicon"
    graph.params["source"] = "UI-PRMD Vicon joint centres, subjects " + ",".join(SUBJECTS)
    graph.save(args.out / "uiprmd-graph.npz")
    print(f"uiprmd graph: {len(graph.poses)} nodes from {len(clips)} clips")

    databases = {"embedded": default_graph()}
    bandai = args.data / "bandai_namco" / "dataset-1"
    if bandai.is_dir():
        clips = load_clips([bandai], progress=True)
        databases["bandai"] = FilteredPoseGraph.build(clips, thres1=0.2, mirror=True)
    for name, database in databases.items():
        sensor_map, _ = fit_sensor_maps(
            sensor,
            truth,
            sensor="kinect-v2",
            truth="vicon",
            database=database.poses,
            database_name=name,
        )
        sensor_map.save(args.out / f"kinect-v2-to-{name}.json")
        print(f"{sensor_map!r}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
