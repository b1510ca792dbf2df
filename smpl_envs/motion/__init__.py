"""Motion files -> reference motion for the humanoid: loaders, kinematics, the MotionLib."""

from .library import MotionLib, MotionState, available_clips, load_motion, load_motions
from .loaders import MotionFileError, ShapeOnlyFile, read_motion_file
from .motion import FPS, Motion, RawMotion

__all__ = [
    "FPS", "Motion", "MotionFileError", "MotionLib", "MotionState", "RawMotion", "ShapeOnlyFile",
    "available_clips", "load_motion", "load_motions", "read_motion_file",
]
