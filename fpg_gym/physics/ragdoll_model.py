"""Body model of the ragdoll: segment masses, capsule radii and inertias per Kinect bone.

Each of the 19 bones of :data:`fpg_gym.core.skeleton.BONES` is one rigid capsule segment. Masses
come from the segment mass fractions of de Leva (1996), "Adjustments to Zatsiorsky–Seluyanov's
segment inertia parameters", *Journal of Biomechanics* 29(9):1223–1230, Table 4 (males: head 6.94 %,
upper/middle/lower trunk 15.96/16.33/11.17 %, upper arm 2.71 %, forearm 1.62 %, hand 0.61 %,
thigh 14.16 %, shank 4.33 %, foot 1.37 %; the fractions sum to 100 %). Kinect-20 splits the
trunk differently from de Leva, so the trunk is shared out as documented in
:data:`MASS_FRACTION_BY_CHILD` (each pelvis half carries half the lower trunk, the
HipCenter–Spine bone the middle trunk, each clavicle a sixth of the upper trunk and the
Spine–ShoulderCenter bone the rest of it).

The body mass defaults to de Leva's male reference, 73.0 kg at 1.741 m, scaled with the cube of
the user's size (sum of bone lengths over that of :data:`fpg_gym.core.poses.DEFAULT_BONE_LENGTHS`,
the 1.75 m default body). Each capsule's radius is that of the cylinder of the bone's length
with the segment's mass at a whole-body density of 1050 kg/m³ (Winter, *Biomechanics and Motor
Control of Human Movement*, 4th ed., 2009, Table 4.1 lists segment densities of about 1.0–1.2
g/cm³), except the flat foot (:data:`RADIUS_CAP_FRACTIONS`); its inertia is that cylinder's,
with the centre of mass at the bone's midpoint.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from fpg_gym.core import poses, skeleton

#: de Leva (1996) Table 4, male: mean body mass (kg) of the reference sample (stature 1.741 m).
REFERENCE_BODY_MASS_KG: Final[float] = 73.0
#: Whole-body density used to size the capsules (kg/m³).
BODY_DENSITY: Final[float] = 1050.0
GRAVITY: Final[float] = 9.81

_UPT, _MPT, _LPT = 15.96, 16.33, 11.17  # de Leva upper, middle, lower trunk (% body mass)

#: Percent of body mass carried by the bone that ends at each joint (de Leva 1996, Table 4).
MASS_FRACTION_BY_CHILD: Final[dict[str, float]] = {
    "Spine": _MPT,  # HipCenter-Spine: middle trunk
    "ShoulderCenter": _UPT * 4.0 / 6.0,  # Spine-ShoulderCenter: upper trunk less the clavicles
    "Head": 6.94,  # head and neck
    "ShoulderLeft": _UPT / 6.0,  # shoulder girdle
    "ElbowLeft": 2.71,  # upper arm
    "WristLeft": 1.62,  # forearm
    "HandLeft": 0.61,  # hand
    "ShoulderRight": _UPT / 6.0,
    "ElbowRight": 2.71,
    "WristRight": 1.62,
    "HandRight": 0.61,
    "HipLeft": _LPT / 2.0,  # pelvis half: lower trunk
    "KneeLeft": 14.16,  # thigh
    "AnkleLeft": 4.33,  # shank
    "FootLeft": 1.37,  # foot
    "HipRight": _LPT / 2.0,
    "KneeRight": 14.16,
    "AnkleRight": 4.33,
    "FootRight": 1.37,
}

#: Mass fraction per bone, in :data:`skeleton.BONES` order (sums to 1).
MASS_FRACTIONS: Final[np.ndarray] = (
    np.array([MASS_FRACTION_BY_CHILD[skeleton.JOINT_NAMES[c]] for _, c in skeleton.BONES]) / 100.0
)
MASS_FRACTIONS.flags.writeable = False

#: Largest capsule radius as a fraction of the bone length, per bone: the foot is flat and its
#: Kinect joints (ankle, toes) lie a few centimetres above the sole, so its capsule is kept thin
#: enough that a foot whose joints sit at their usual height does not cut into the floor.
RADIUS_CAP_FRACTIONS: Final[np.ndarray] = np.array(
    [0.25 if skeleton.JOINT_NAMES[c].startswith("Foot") else np.inf for _, c in skeleton.BONES]
)
RADIUS_CAP_FRACTIONS.flags.writeable = False

_MIN_BONE_LENGTH_M = 0.01


@dataclass(frozen=True)
class BodyModel:
    """Masses, sizes and gains of the 19 capsule segments, in :data:`skeleton.BONES` order.

    Attributes
    ----------
    bone_lengths : ndarray, shape (19,)
        Capsule lengths between joint centres (m).
    masses : ndarray, shape (19,)
        Segment masses (kg).
    radii : ndarray, shape (19,)
        Capsule radii (m).
    inertia : ndarray, shape (19, 3)
        Principal moments (kg m²) about the centre of mass: two across the bone, then along it.
    total_mass : float
        Body mass (kg).
    """

    bone_lengths: np.ndarray
    masses: np.ndarray
    radii: np.ndarray
    inertia: np.ndarray
    total_mass: float


def default_body_mass(bone_lengths: np.ndarray) -> float:
    """de Leva's 73 kg reference scaled by the cube of the size ratio to the default body."""
    scale = float(np.sum(bone_lengths) / np.sum(poses.DEFAULT_BONE_LENGTHS))
    return REFERENCE_BODY_MASS_KG * scale**3


def build_body_model(
    bone_lengths: np.ndarray | None = None, body_mass: float | None = None
) -> BodyModel:
    """Segment parameters for a body with the given bone lengths.

    Parameters
    ----------
    bone_lengths : array_like, shape (19,), optional
        Bone lengths in metres in :data:`skeleton.BONES` order;
        :data:`poses.DEFAULT_BONE_LENGTHS` when omitted.
    body_mass : float, optional
        Total mass in kg; :func:`default_body_mass` when omitted.

    Raises
    ------
    ValueError
        If the lengths are not 19 finite values of at least 1 cm, or the mass is not positive.
    """
    lengths = (
        np.array(poses.DEFAULT_BONE_LENGTHS, dtype=np.float64)
        if bone_lengths is None
        else np.asarray(bone_lengths, dtype=np.float64)
    )
    if lengths.shape != (skeleton.NUM_BONES,):
        raise ValueError(f"bone_lengths: expected shape (19,), got {lengths.shape}")
    if not np.all(np.isfinite(lengths)) or np.any(lengths < _MIN_BONE_LENGTH_M):
        bad = int(np.argmax(~np.isfinite(lengths) | (lengths < _MIN_BONE_LENGTH_M)))
        raise ValueError(
            f"bone_lengths: every bone must be a finite length of at least "
            f"{_MIN_BONE_LENGTH_M} m; bone {skeleton.BONE_NAMES[bad]} is {lengths[bad]!r}"
        )
    mass = default_body_mass(lengths) if body_mass is None else float(body_mass)
    if not (np.isfinite(mass) and mass > 0):
        raise ValueError(f"body_mass: expected a positive number of kg, got {body_mass!r}")

    masses = MASS_FRACTIONS * mass
    radii = np.sqrt(masses / (BODY_DENSITY * np.pi * lengths))  # equal-volume cylinder
    radii = np.minimum(radii, RADIUS_CAP_FRACTIONS * lengths)
    across = masses * (3.0 * radii**2 + lengths**2) / 12.0
    inertia = np.stack([across, across, masses * radii**2 / 2.0], axis=-1)
    return BodyModel(
        bone_lengths=lengths,
        masses=masses,
        radii=radii,
        inertia=inertia,
        total_mass=mass,
    )
