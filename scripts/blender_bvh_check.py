"""Import a BVH written by ``fpg-gym export`` into Blender and save the joints' world positions.

Run with Blender's Python (the ``bpy`` module: ``pip install bpy`` in a separate environment, about
1 GB, or ``blender --background --python scripts/blender_bvh_check.py -- FILE.bvh``)::

    python scripts/blender_bvh_check.py rec.bvh      # writes rec.blender.npy

The output is ``(T, 20, 3)`` in the file's axes and metres (Y up), Kinect-20 order, so that it
compares directly with ``fpg_gym.io.read_bvh(FILE, BVH_JOINT_MAP, units="cm", fps=None)`` (see
docs/output.md). Needs only bpy and numpy (both in Blender's Python).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

try:
    import bpy
except ModuleNotFoundError:  # run outside Blender's Python: say how to run it
    sys.exit(
        "blender_bvh_check.py needs Blender's Python (the bpy module): run it as "
        "`blender --background --python scripts/blender_bvh_check.py -- FILE.bvh` or install "
        "bpy in a separate environment (see this script's docstring)"
    )

#: Kinect-20 joint names (fpg_gym.core.skeleton.JOINT_NAMES), repeated so that only bpy is needed.
JOINTS = (
    "HipCenter Spine ShoulderCenter Head ShoulderLeft ElbowLeft WristLeft HandLeft ShoulderRight "
    "ElbowRight WristRight HandRight HipLeft KneeLeft AnkleLeft FootLeft HipRight KneeRight "
    "AnkleRight FootRight"
).split()


def main(path: Path) -> Path:
    """Import ``path`` (centimetres, Y up) and write the joint heads of every frame."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_anim.bvh(
        filepath=str(path),
        global_scale=0.01,  # centimetres -> metres
        axis_forward="-Z",
        axis_up="Y",
        update_scene_fps=True,
        update_scene_duration=True,
    )
    armature = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    scene = bpy.context.scene
    frames = []
    first, last = (round(f) for f in armature.animation_data.action.frame_range)
    for frame in range(first, last + 1):
        scene.frame_set(frame)
        evaluated = armature.evaluated_get(bpy.context.evaluated_depsgraph_get())
        heads = [evaluated.matrix_world @ evaluated.pose.bones[n].head for n in JOINTS]
        # Blender is Z up: back to the file's Y-up axes (x, y, z) = (x, z, -y)
        frames.append([[h.x, h.z, -h.y] for h in heads])
    out = path.with_suffix(".blender.npy")
    np.save(out, np.array(frames))
    print(f"{path}: {len(armature.data.bones)} bones, {len(frames)} frames -> {out}")
    return out


if __name__ == "__main__":
    arguments = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    main(Path(arguments[0]))
