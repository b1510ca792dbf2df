"""smpl-envs: physics-based SMPL humanoid control on MuJoCo."""

__version__ = "0.1.0"
