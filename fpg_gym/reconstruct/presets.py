"""Pipelines by sensor: what a recording gets when no tuning flag is given.

A recording says which sensor made it (:func:`sensor_of`: ``metadata["sensor"]``, else its
reader's format; ``--sensor`` overrides). Each sensor has a profile
(:data:`SENSOR_PROFILES`) and :func:`pipeline` turns a profile, a preset and a pose graph into
:class:`~fpg_gym.reconstruct.ReconstructorConfig` settings:

``auto`` (the default)
    The best pipeline measured on real data for the sensor (``docs/real-data.md``):

    * **kinect-v2** (paired with Vicon in UI-PRMD, so everything is fitted): the sensor is mapped
      to marker-based joint centres (:func:`fpg_gym.definitions.packaged_map`
      ``"kinect-v2-to-vicon"``) and its bone vectors corrected by the packaged bone model
      (:mod:`fpg_gym.reconstruct.bone_model`); the database gets the sensor in its own
      definitions (the same map for a database of joint centres, else that map followed by the
      database's definitions fitted without pairs, :func:`fpg_gym.definitions.fit_to_database`,
      with the output calibrated back online); the fusion
      (:mod:`fpg_gym.reconstruct.fusion`) keeps the sensor where it is trusted and the
      reconstruction where it is not. Its default database is the packaged UI-PRMD one.
    * **simulated** (the simulator's streams, scored in the clip's definitions): the
      reconstruction as it was (temporal defaults, no map, no fusion).
    * **any other sensor** (Kinect v1, Azure Kinect, a tracker; no paired data here): the output
      calibrated online to the sensor's own tracked joints and the fusion, with a one-line note.

``papers``
    The pipeline of Shum 2013 and FPG 2016: no maps, no temporal stage beyond the papers', no
    bone settling, no fusion.

Explicit tuning flags (maps, sensor blend) replace the preset: the reconstruction then runs
with exactly the settings given (``manual``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fpg_gym.definitions import (
    KINECT_V2_TO_VICON,
    ComposedMap,
    DefinitionMap,
    PoseMap,
    fit_to_database,
    packaged_map,
)
from fpg_gym.graph import packaged_graph
from fpg_gym.reconstruct.bone_model import LinearBoneModel, packaged_bone_model
from fpg_gym.reconstruct.bones import BoneSettlingConfig
from fpg_gym.reconstruct.fusion import FusionConfig
from fpg_gym.reconstruct.temporal import TemporalConfig

__all__ = [
    "PRESETS",
    "SENSOR_PROFILES",
    "TUNING_OPTIONS",
    "Pipeline",
    "SensorProfile",
    "SensorResources",
    "choose_pipeline",
    "default_graph_name",
    "pipeline",
    "sensor_of",
]

#: Preset names (``--preset``).
PRESETS: tuple[str, ...] = ("auto", "papers")
#: The sensor of each reader format that does not name one.
_SENSOR_OF_FORMAT = {
    "kinect_v2": "kinect-v2",
    "ui-prmd-kinect": "kinect-v2",
    "ntu": "kinect-v2",
    "msrc12": "kinect-v1",
    "azure_kinect": "azure-kinect",
    "simulated": "simulated",
}
#: ``graph.params["definitions"]`` of a database of marker-based joint centres.
REFERENCE_DEFINITIONS = "vicon"
#: Reconstructor settings that, given explicitly, replace the preset (``manual``).
TUNING_OPTIONS: tuple[str, ...] = (
    "sensor_map",
    "output_map",
    "calibrate_output",
    "calibration_map",
    "sensor_blend",
)


@dataclass(frozen=True)
class SensorProfile:
    """What the package knows of a sensor.

    Attributes
    ----------
    name : str
    fitted : bool
        Whether paired data fitted a map, a bone model and a database for it (packaged).
    calibrate : bool
        Whether the output is calibrated online to the sensor's own joints.
    fusion : bool
        Whether the fusion keeps the sensor where it is trusted.
    default_graph : str
        The database ``--graph default`` gives: ``"embedded"`` or ``"uiprmd"``.
    """

    name: str
    fitted: bool = False
    calibrate: bool = True
    fusion: bool = True
    default_graph: str = "embedded"


#: Every known sensor profile, by name (unknown names get the ``"unknown"`` profile).
SENSOR_PROFILES: dict[str, SensorProfile] = {
    p.name: p
    for p in (
        SensorProfile("kinect-v2", fitted=True, calibrate=False, default_graph="uiprmd"),
        SensorProfile("simulated", calibrate=False, fusion=False),
        SensorProfile("kinect-v1"),
        SensorProfile("azure-kinect"),
        SensorProfile("unknown"),
    )
}


def sensor_of(recording: Any, override: str | None = None) -> str:
    """The sensor that made ``recording``: ``override``, ``metadata["sensor"]``, the reader
    format's sensor, or ``"unknown"``."""
    if override:
        return str(override)
    metadata = getattr(recording, "metadata", None) or {}
    named = metadata.get("sensor")
    if isinstance(named, str) and named:
        return named
    return _SENSOR_OF_FORMAT.get(str(metadata.get("format", "")), "unknown")


@dataclass(frozen=True)
class SensorResources:
    """What paired data fitted for a sensor: its map to marker-based joint centres, its bone
    model and reference poses in those centres' definitions (to fit a database's).

    :meth:`packaged` gives the resources shipped for a sensor (Kinect v2: fitted on UI-PRMD's
    eight shared subjects); an evaluation passes resources fitted without the scored subjects.
    """

    to_reference: DefinitionMap
    bone_model: LinearBoneModel | None
    reference_poses: np.ndarray

    @classmethod
    def packaged(cls, sensor: str) -> SensorResources | None:
        """The packaged resources of ``sensor`` (None when the package has none)."""
        if sensor != "kinect-v2":
            return None
        return cls(
            to_reference=packaged_map(KINECT_V2_TO_VICON),
            bone_model=packaged_bone_model(KINECT_V2_TO_VICON),
            reference_poses=packaged_graph("uiprmd").poses,
        )


@dataclass(frozen=True)
class Pipeline:
    """Reconstructor settings chosen for a sensor (:func:`pipeline`).

    Attributes
    ----------
    preset : str
        ``"auto"``, ``"papers"`` or ``"manual"``.
    sensor : str
    options : dict
        :class:`~fpg_gym.reconstruct.ReconstructorConfig` fields.
    description : str
        One line for the user.
    note : str
        A caveat to print (empty when none).
    optimizer : str or None
        The optimiser that measured best with these settings, for commands where the user names
        none (None: the papers' ``local-search``).
    """

    preset: str
    sensor: str
    options: dict[str, Any]
    description: str
    note: str = ""
    optimizer: str | None = None

    def summary(self) -> dict[str, Any]:
        """JSON-ready facts (stored in outputs' metadata and ``compare``'s config)."""
        return {
            "preset": self.preset,
            "sensor": self.sensor,
            "description": self.description,
            **({"note": self.note} if self.note else {}),
            **({"optimizer": self.optimizer} if self.optimizer else {}),
        }


def _database_map(resources: SensorResources, graph: Any) -> tuple[PoseMap, bool]:
    """The sensor -> database map and whether the database is in the reference definitions."""
    params = getattr(graph, "params", None) or {}
    if params.get("definitions") == REFERENCE_DEFINITIONS:
        return resources.to_reference, True
    to_database = fit_to_database(
        resources.reference_poses,
        np.asarray(graph.poses),
        source=REFERENCE_DEFINITIONS,
        target="database",
    )
    return ComposedMap((resources.to_reference, to_database)), False


def pipeline(
    preset: str,
    sensor: str,
    graph: Any,
    *,
    resources: SensorResources | None = None,
) -> Pipeline:
    """The reconstructor settings of ``preset`` for ``sensor`` and ``graph``.

    Parameters
    ----------
    preset : {"auto", "papers"}
    sensor : str
        A name of :data:`SENSOR_PROFILES` (others are ``"unknown"``).
    graph : FilteredPoseGraph-like
        The database (its ``poses``; ``params["definitions"] == "vicon"`` marks a database of
        marker-based joint centres).
    resources : SensorResources, optional
        The sensor's fitted resources; the packaged ones when omitted.

    Raises
    ------
    ValueError
        On an unknown preset.
    """
    if preset not in PRESETS:
        raise ValueError(f"preset: expected one of {', '.join(PRESETS)}, got {preset!r}")
    profile = SENSOR_PROFILES.get(sensor, SENSOR_PROFILES["unknown"])
    if preset == "papers":
        return Pipeline(
            "papers",
            sensor,
            {
                "temporal": TemporalConfig.off(),
                "bones": BoneSettlingConfig(enabled=False),
            },
            "the papers' pipeline (no maps, no temporal stage, no bone settling, no fusion)",
        )
    fusion = FusionConfig(enabled=profile.fusion)
    if profile.fitted:
        resources = resources or SensorResources.packaged(profile.name)
    if profile.fitted and resources is not None:
        sensor_map, reference = _database_map(resources, graph)
        options: dict[str, Any] = {
            "sensor_map": sensor_map,
            "fusion": fusion,
            "bone_model": resources.bone_model,
        }
        if not reference:
            options.update(calibrate_output=True, calibration_map=resources.to_reference)
        where = "joint centres" if reference else "its definitions fitted, output calibrated"
        return Pipeline(
            "auto",
            sensor,
            options,
            f"{sensor}: mapped to marker joint centres, bone model, database in {where}, "
            "fusion of sensor and reconstruction",
            # The closed form carries lost limbs better on UI-PRMD (docs/real-data.md).
            optimizer="closed-form",
        )
    if not profile.fusion:
        return Pipeline("auto", sensor, {}, f"{sensor}: the reconstruction (no map, no fusion)")
    return Pipeline(
        "auto",
        sensor,
        {"calibrate_output": True, "fusion": fusion},
        f"{sensor}: output calibrated online to the sensor's joints, fusion of sensor and "
        "reconstruction",
        note=(
            f"no paired data for sensor {sensor!r}: the output is in the sensor's own joint "
            "definitions (--sensor kinect-v2 if it is one; --preset papers for the papers')"
        ),
    )


def default_graph_name(sensor: str) -> str:
    """The database ``--graph default`` names for ``sensor`` (``"embedded"`` or ``"uiprmd"``)."""
    return SENSOR_PROFILES.get(sensor, SENSOR_PROFILES["unknown"]).default_graph


def choose_pipeline(
    preset: str,
    sensor: str,
    graph: Any,
    tuning: dict[str, Any] | None = None,
    *,
    resources: SensorResources | None = None,
) -> Pipeline:
    """:func:`pipeline`, unless ``tuning`` holds explicit settings of :data:`TUNING_OPTIONS`:
    then exactly those (``preset == "manual"``)."""
    given = {k: v for k, v in (tuning or {}).items() if k in TUNING_OPTIONS and v is not None}
    if given.get("calibrate_output") is False:
        del given["calibrate_output"]
    if given:
        names = ", ".join(sorted(given))
        return Pipeline("manual", sensor, given, f"{sensor}: the settings given ({names})")
    return pipeline(preset, sensor, graph, resources=resources)
