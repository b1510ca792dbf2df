"""The SMPL humanoid: skeleton facts and the MuJoCo model built from them."""

from .builder import (PHYSICS_TIMESTEP, HumanoidAddresses, build_humanoid, build_spec, humanoid_addresses,
                      standing_height)
from .skeleton import (
    ACTION_SCALE, BODY_NAMES, HINGE_NAMES, MEAN_SKELETON, NUM_BODIES, NUM_HINGES, PARENTS,
    SMPL_JOINT_OF_BODY, Geom, Skeleton,
)

__all__ = [
    "ACTION_SCALE", "BODY_NAMES", "HumanoidAddresses", "humanoid_addresses", "HINGE_NAMES", "MEAN_SKELETON", "NUM_BODIES", "NUM_HINGES",
    "PARENTS", "PHYSICS_TIMESTEP", "SMPL_JOINT_OF_BODY", "Geom", "Skeleton", "build_humanoid",
    "build_spec", "standing_height",
]
