"""File formats: mocap clips (BVH, DeepMimic, positions ``.npz``), Kinect recordings and the
embedded default clips.

The package imports nothing heavy when imported: each name below is loaded from its module on
first use (``from fpg_gym.io import read_recording`` imports :mod:`fpg_gym.io.kinect` then).

========================  =======================================================================
``mocap``                 :func:`read_clip` (format from the file name), :func:`load_clips` (files,
                          folders, ``default``; parallel), :func:`resolve_clips` (``--clips``)
``bvh``, ``bvh_write``    BVH clips read (:func:`read_bvh`, Bandai Namco's map) and written
``deepmimic``             the DeepMimic clips and the embedded default (:func:`load_default_clips`)
``positions``             Kinect-20 positions ``.npz`` clips
``kinect``                Kinect recordings in every supported format (:func:`read_recording`)
``recording``             :class:`Recording` and :func:`write_recording`
``clip``                  :class:`Clip`
========================  =======================================================================
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fpg_gym.core.errors import DataFormatError
    from fpg_gym.io.bvh import BANDAI_NAMCO_MAP, BvhPoint, read_bvh
    from fpg_gym.io.bvh_write import BVH_JOINT_MAP, write_bvh
    from fpg_gym.io.clip import Clip
    from fpg_gym.io.deepmimic import DEFAULT_CLIP_NAMES, load_default_clips, read_deepmimic
    from fpg_gym.io.kinect import read_recording
    from fpg_gym.io.mocap import (
        MOCAP_FORMATS,
        expand_inputs,
        find_mocap_files,
        load_clips,
        read_clip,
        resolve_clips,
    )
    from fpg_gym.io.positions import read_positions, write_positions
    from fpg_gym.io.recording import Recording, write_recording

__all__ = [
    "BANDAI_NAMCO_MAP",
    "BVH_JOINT_MAP",
    "DEFAULT_CLIP_NAMES",
    "MOCAP_FORMATS",
    "BvhPoint",
    "Clip",
    "DataFormatError",
    "Recording",
    "expand_inputs",
    "find_mocap_files",
    "load_clips",
    "load_default_clips",
    "read_bvh",
    "read_clip",
    "read_deepmimic",
    "read_positions",
    "read_recording",
    "resolve_clips",
    "write_bvh",
    "write_positions",
    "write_recording",
]

#: The module of each name of the package (loaded on first use).
_HOMES: dict[str, str] = {
    "DataFormatError": "fpg_gym.core.errors",
    "BANDAI_NAMCO_MAP": "fpg_gym.io.bvh",
    "BvhPoint": "fpg_gym.io.bvh",
    "read_bvh": "fpg_gym.io.bvh",
    "BVH_JOINT_MAP": "fpg_gym.io.bvh_write",
    "write_bvh": "fpg_gym.io.bvh_write",
    "Clip": "fpg_gym.io.clip",
    "DEFAULT_CLIP_NAMES": "fpg_gym.io.deepmimic",
    "load_default_clips": "fpg_gym.io.deepmimic",
    "read_deepmimic": "fpg_gym.io.deepmimic",
    "read_recording": "fpg_gym.io.kinect",
    "MOCAP_FORMATS": "fpg_gym.io.mocap",
    "expand_inputs": "fpg_gym.io.mocap",
    "find_mocap_files": "fpg_gym.io.mocap",
    "load_clips": "fpg_gym.io.mocap",
    "read_clip": "fpg_gym.io.mocap",
    "resolve_clips": "fpg_gym.io.mocap",
    "read_positions": "fpg_gym.io.positions",
    "write_positions": "fpg_gym.io.positions",
    "Recording": "fpg_gym.io.recording",
    "write_recording": "fpg_gym.io.recording",
}


def __getattr__(name: str) -> Any:
    """Load a name of the package from its module on first use (PEP 562)."""
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_HOMES})
