"""The SMPL humanoid as MJCF, built with `mujoco.MjSpec` from a `Skeleton`.

24 bodies whose rest frames are world-aligned, each but the pelvis with x, y, z hinges at its
joint; a free pelvis; MuJoCo position actuators (PD inside the solver, implicitfast integration).
Gains and torque limits are REFERENCE.md's, scaled by body mass / 74 kg so every body shape gets
the same control authority per kilogram.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from .kinematics import forward_kinematics, lowest_point
from .skeleton import (
    ACTION_SCALE, BODY_NAMES, HINGE_AXES, KD, KP, MEAN_MASS, MEAN_SKELETON, PARENTS, TORQUE_LIMIT,
    Skeleton, anatomical_limits,
)

PHYSICS_TIMESTEP = 1.0 / 120.0  # measured: stands at zero action and runs fast (docs/humanoid.md, "Timing")
ARMATURE = 0.02
FRICTION = (1.0, 0.005, 0.0001)

# Pairs of bodies that touch at rest or cannot meaningfully collide (besides parent-child, which
# MuJoCo filters by default).
EXCLUDED_PAIRS = (
    ("Torso", "Chest"), ("Head", "Chest"), ("L_Shoulder", "Chest"), ("R_Shoulder", "Chest"),
    ("L_Knee", "R_Ankle"), ("L_Knee", "R_Toe"), ("R_Knee", "L_Ankle"), ("R_Knee", "L_Toe"),
    ("Pelvis", "Spine"), ("L_Hip", "R_Hip"), ("Chest", "L_Thorax"), ("Chest", "R_Thorax"),
    ("Neck", "L_Thorax"), ("Neck", "R_Thorax"), ("L_Thorax", "R_Thorax"),
)
_GEOM_TYPES = {
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
    "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "mesh": mujoco.mjtGeom.mjGEOM_MESH,
}
_SKIN = (0.84, 0.62, 0.48, 1.0)
TRACK_CAMERA_OFFSET = np.array([2.6, -2.6, 0.55])  # front-left three-quarter view of the pelvis


def _look_at(eye, target) -> np.ndarray:
    """MuJoCo camera xyaxes (right, up) for a camera at `eye` looking at `target`, z up."""
    forward = np.asarray(target, float) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return np.concatenate([right, np.cross(right, forward)])


def standing_height(skeleton: Skeleton) -> float:
    """Pelvis height at which the rest pose (all hinges at zero) stands with its soles on z = 0."""
    ident = np.tile([1.0, 0.0, 0.0, 0.0], (1, len(BODY_NAMES), 1))
    pos, quat = forward_kinematics(np.zeros((1, 3)), ident, skeleton.offsets)
    return float(-lowest_point(pos, quat, skeleton)[0])


def _add_scene(spec: mujoco.MjSpec) -> None:
    spec.add_texture(name="skybox", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
                     builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT, rgb1=[0.55, 0.7, 0.85],
                     rgb2=[0.1, 0.12, 0.15], width=256, height=256)
    spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D,
                     builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, rgb1=[0.32, 0.34, 0.37],
                     rgb2=[0.26, 0.28, 0.31], mark=mujoco.mjtMark.mjMARK_EDGE,
                     markrgb=[0.6, 0.62, 0.65], width=300, height=300)
    floor_mat = spec.add_material(name="floor", texrepeat=[1, 1], texuniform=True, reflectance=0.05)
    floor_mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
    spec.add_material(name="skin", rgba=_SKIN, specular=0.2, shininess=0.2)
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.5, 0.5, 0.5]
    spec.visual.global_.offwidth = 1280
    spec.visual.global_.offheight = 960
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[100, 100, 0.05],
                            material="floor", friction=FRICTION, condim=3)
    spec.worldbody.add_light(name="sun", pos=[0, 0, 6], dir=[0, 0.2, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
                             diffuse=[0.6, 0.6, 0.6], castshadow=True)


def build_spec(
    skeleton: Skeleton = MEAN_SKELETON,
    joint_limits: str = "none",
    timestep: float = PHYSICS_TIMESTEP,
    scene: bool = True,
) -> mujoco.MjSpec:
    """The humanoid's MjSpec (uncompiled), for callers that add objects before compiling."""
    if joint_limits not in ("none", "anatomical"):
        raise ValueError(f"joint_limits must be 'none' or 'anatomical', got {joint_limits!r}")
    spec = mujoco.MjSpec()
    spec.modelname = "smpl_humanoid"
    spec.compiler.degree = False
    spec.option.timestep = timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    if scene:
        _add_scene(spec)
    gain = skeleton.mass / MEAN_MASS
    limits = anatomical_limits() if joint_limits == "anatomical" else None

    bodies = []
    for i, name in enumerate(BODY_NAMES):
        if i == 0:
            body = spec.worldbody.add_body(name=name, pos=[0, 0, standing_height(skeleton)])
            body.add_freejoint(name="root")
            body.add_camera(name="track", mode=mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM,
                            pos=TRACK_CAMERA_OFFSET, xyaxes=_look_at(TRACK_CAMERA_OFFSET, [0, 0, -0.15]))
        else:
            body = bodies[PARENTS[i]].add_body(name=name, pos=skeleton.offsets[i])
            for k, axis in enumerate(HINGE_AXES):
                j = 3 * (i - 1) + k
                # The PD's D term is joint damping, not actuator kv: implicitfast integrates joint
                # damping implicitly always, but skips the velocity derivative of force-limited
                # actuators, and with kv on the actuator random actions diverge at this timestep.
                joint = body.add_joint(name=f"{name}_{axis}", type=mujoco.mjtJoint.mjJNT_HINGE,
                                       axis=np.eye(3)[k], armature=ARMATURE, damping=KD[j] * gain)
                if limits is not None:
                    joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
                    joint.range = limits[j]
        geom = skeleton.geoms[i]
        kwargs = dict(name=f"{name}_geom", type=_GEOM_TYPES[geom.kind], mass=geom.mass,
                      friction=FRICTION, condim=3, material="skin" if scene else "",
                      rgba=_SKIN)
        if geom.kind == "capsule":
            kwargs.update(fromto=geom.fromto, size=[geom.size[0], 0, 0])
        elif geom.kind == "mesh":
            spec.add_mesh(name=f"{name}_hull", uservert=np.asarray(geom.vertices, float).ravel())
            kwargs.update(meshname=f"{name}_hull")
        else:
            kwargs.update(pos=geom.pos, size=list(geom.size) + [0] * (3 - len(geom.size)))
        body.add_geom(**kwargs)
        bodies.append(body)

    for a, b in EXCLUDED_PAIRS:
        spec.add_exclude(bodyname1=a, bodyname2=b)
    for j, name in enumerate(f"{b}_{a}" for b in BODY_NAMES[1:] for a in HINGE_AXES):
        act = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=KP[j] * gain)
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.ctrlrange = [-ACTION_SCALE[j], ACTION_SCALE[j]]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-TORQUE_LIMIT[j] * gain, TORQUE_LIMIT[j] * gain]
    return spec


def build_humanoid(
    betas=None,
    gender: str = "neutral",
    smpl_model_path: str | Path | None = None,
    *,
    mesh: bool = False,
    joint_limits: str = "none",
    timestep: float = PHYSICS_TIMESTEP,
    skeleton: Skeleton | None = None,
    return_spec: bool = False,
):
    """Compile the SMPL humanoid.

    With no arguments: the neutral mean shape of REFERENCE.md (no SMPL file needed). With
    `smpl_model_path` (the user's own SMPL model, .pkl or .npz): the body of `betas` for that
    model, capsule geometry fitted to the skinned mesh, or the convex hull per bone if `mesh`.
    `joint_limits` is "none" (hinges wide open, as PHC trains) or "anatomical".
    Returns the `mujoco.MjModel`, or `(model, spec)` if `return_spec`.
    """
    if skeleton is None:
        if smpl_model_path is None:
            if betas is not None and np.any(np.asarray(betas) != 0):
                raise ValueError("betas other than zero need smpl_model_path (your SMPL model file)")
            if mesh:
                raise ValueError("mesh=True needs smpl_model_path: the hulls come from the SMPL mesh")
            skeleton = MEAN_SKELETON
        else:
            from .smpl_model import skeleton_from_smpl

            skeleton = skeleton_from_smpl(smpl_model_path, betas=betas, gender=gender, mesh=mesh)
    spec = build_spec(skeleton, joint_limits=joint_limits, timestep=timestep)
    model = spec.compile()
    return (model, spec) if return_spec else model


@dataclass(frozen=True)
class HumanoidAddresses:
    """Where the humanoid lives inside a compiled model that may also hold other things (a box, a
    target marker, a terrain): the simulator and the features read the humanoid through these,
    never through fixed offsets such as `xpos[1:]` or `qpos[:, 7:]`.

    body_ids (24,) model body ids in BODY_NAMES order; root (model body id of the pelvis);
    qpos / qvel: slices of the humanoid's free root + 69 hinges (76 / 75 entries);
    actuators: slice of its 69 position actuators; geom_ids (24,) one collision geom per body.
    """

    body_ids: np.ndarray
    root: int
    qpos: slice
    qvel: slice
    actuators: slice
    geom_ids: np.ndarray

    @property
    def dof_qpos(self) -> slice:
        """The 69 hinge angles inside qpos."""
        return slice(self.qpos.start + 7, self.qpos.stop)

    @property
    def dof_qvel(self) -> slice:
        """The 69 hinge rates inside qvel."""
        return slice(self.qvel.start + 6, self.qvel.stop)


def humanoid_addresses(model: mujoco.MjModel) -> HumanoidAddresses:
    """The humanoid's addresses in `model` (built by `build_spec`, possibly with more added)."""
    body_ids = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n) for n in BODY_NAMES])
    if (body_ids < 0).any():
        missing = [n for n, i in zip(BODY_NAMES, body_ids) if i < 0]
        raise ValueError(f"model has no humanoid bodies {missing}: build it with smpl_envs.humanoid.build_spec")
    root = int(body_ids[0])
    jnt = model.body_jntadr[root]
    q0, v0 = int(model.jnt_qposadr[jnt]), int(model.jnt_dofadr[jnt])
    hinges = [f"{b}_{a}" for b in BODY_NAMES[1:] for a in HINGE_AXES]
    acts = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in hinges])
    qadr = np.array([model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in hinges])
    # The builder lays the humanoid out contiguously (root then hinges in BODY_NAMES order); the
    # slices below rely on that, so check it instead of assuming it.
    if not (np.array_equal(qadr, q0 + 7 + np.arange(len(hinges)))
            and np.array_equal(acts, acts[0] + np.arange(len(hinges)))):
        raise ValueError("the humanoid's joints or actuators are not contiguous in this model")
    geom_ids = np.array([model.body_geomadr[b] for b in body_ids])
    return HumanoidAddresses(body_ids=body_ids, root=root, qpos=slice(q0, q0 + 7 + len(hinges)),
                             qvel=slice(v0, v0 + 6 + len(hinges)), actuators=slice(int(acts[0]), int(acts[0]) + len(hinges)),
                             geom_ids=geom_ids)
