"""pybullet's DeepMimic humanoid as pybullet loads it: the source of the DeepMimic reader's table.

:mod:`fpg_gym.io.deepmimic` reads its kinematic tree from
:data:`fpg_gym.io.deepmimic.HUMANOID_TABLE` (so that reading a clip needs no physics engine);
:func:`humanoid_model_from_pybullet` reads it from pybullet, and the tests check that the two
are equal to the last bit; :func:`write_humanoid_table` writes the table again (after a
pybullet upgrade changed the humanoid).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from fpg_gym.io.deepmimic import HUMANOID_TABLE, URDF_SCALE, HumanoidModel, model_table
from fpg_gym.physics.pybullet_utils import connect_direct, data_path, pybullet, quiet_stdout

__all__ = ["humanoid_model_from_pybullet", "write_humanoid_table"]


def humanoid_model_from_pybullet() -> HumanoidModel:
    """Read the humanoid's joint offsets and link geometry from pybullet."""
    client = connect_direct()
    try:
        with quiet_stdout():
            body = pybullet.loadURDF(
                str(data_path() / "humanoid" / "humanoid.urdf"),
                globalScaling=URDF_SCALE,
                useFixedBase=True,
                physicsClientId=client,
            )
        count = pybullet.getNumJoints(body, physicsClientId=client)
        names = ["root"]
        parents = [-1]
        world = [np.zeros(3)]  # link frame origins at the rest pose (all rotations identity)
        inertial: dict[str, np.ndarray] = {}
        dims: dict[str, np.ndarray] = {}
        for joint in range(count):
            info = pybullet.getJointInfo(body, joint, physicsClientId=client)
            name = info[12].decode()
            state = pybullet.getLinkState(body, joint, physicsClientId=client)
            world_position = np.array(state[4])
            parent_link = info[16]
            if name == "root":  # the fixed joint base -> root: same origin as the base
                world[0] = world_position
                inertial[name] = np.array(
                    pybullet.getDynamicsInfo(body, joint, physicsClientId=client)[3]
                )
                continue
            parent_name = pybullet.getJointInfo(body, parent_link, physicsClientId=client)[
                12
            ].decode()
            names.append(name)
            parents.append(names.index(parent_name))
            world.append(world_position)
            inertial[name] = np.array(
                pybullet.getDynamicsInfo(body, joint, physicsClientId=client)[3]
            )
            shapes = pybullet.getCollisionShapeData(body, joint, physicsClientId=client)
            dims[name] = np.array(shapes[0][3]) if shapes else np.zeros(3)
    finally:
        pybullet.disconnect(physicsClientId=client)

    world_array = np.array(world)
    offsets = np.array(
        [world_array[i] - (world_array[p] if p >= 0 else 0.0) for i, p in enumerate(parents)]
    )
    wrist_radius = float(dims["right_wrist"][0])
    foot_box_length = float(dims["right_ankle"][0])
    points: dict[tuple[str, str], np.ndarray] = {}
    for link in names:
        points[(link, "joint")] = np.zeros(3)
    points[("neck", "head")] = inertial["neck"]
    for side in ("left", "right"):
        points[(f"{side}_wrist", "hand")] = np.array([0.0, -2.0 * wrist_radius, 0.0])
        box_centre = inertial[f"{side}_ankle"]
        points[(f"{side}_ankle", "foot")] = box_centre + np.array([foot_box_length / 4, 0.0, 0.0])
    return HumanoidModel(tuple(names), tuple(parents), offsets, points)


def write_humanoid_table(path: str | os.PathLike[str] = HUMANOID_TABLE) -> Path:
    """Write :func:`humanoid_model_from_pybullet` as the DeepMimic reader's table (JSON)."""
    path = Path(path)
    path.write_text(json.dumps(model_table(humanoid_model_from_pybullet()), indent=1) + "\n")
    return path
