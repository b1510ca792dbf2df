"""The suite's task ids: the vector class of each task and its time limit, as plain data.

A module of its own, importing nothing, so that code which needs the ids (`policy_settings`)
does not import the package's `__init__`, whose lazy attributes import that code in turn.
"""

# Task id -> (vector class "module:Class" in smpl_envs.envs, time limit in steps or None).
ENV_IDS = {
    "SMPL/Imitation-v0": ("smpl_envs.envs.imitation:ImitationVecEnv", None),
    "SMPL/KeypointImitation-v0": ("smpl_envs.envs.imitation:KeypointImitationVecEnv", None),
    "SMPL/Speed-v0": ("smpl_envs.envs.speed:SpeedVecEnv", 300),
    "SMPL/Reach-v0": ("smpl_envs.envs.reach:ReachVecEnv", 300),
    "SMPL/Strike-v0": ("smpl_envs.envs.strike:StrikeVecEnv", 300),
    "SMPL/VRTracking-v0": ("smpl_envs.envs.vr:VRTrackingVecEnv", None),
    "SMPL/Terrain-v0": ("smpl_envs.envs.terrain:TerrainVecEnv", 300),
    "SMPL/Recovery-v0": ("smpl_envs.envs.recovery:RecoveryVecEnv", 300),
    "SMPL/VideoPose-v0": ("smpl_envs.envs.videopose:VideoPoseVecEnv", None),
}
