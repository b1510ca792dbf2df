"""Real pose estimators' output in: per-frame SMPL parameters, 2D keypoints and camera intrinsics,
as the common video estimators write them, made into a `VideoInput` (no ground truth).

    video = load_estimator_output("out/smpl.npz")                        # one file with everything
    video = load_estimator_output("out/smpl.pkl", keypoints="out/openpose_json/", camera="cam.json")

SMPL parameters (`.npz`, or a `.pkl` / `.json` holding a dict; a dict of per-person dicts, as
VIBE and PHALP write them, needs `person=` unless it holds one person):

| field | shape | |
|---|---|---|
| global_orient | (T, 3) axis-angle, or (T, 3, 3) / (T, 1, 3) / (T, 1, 3, 3) | the root's rotation in the camera frame |
| body_pose | (T, 69) / (T, 23, 3) axis-angle, (T, 63) / (T, 21, 3) (SMPL-X bodies: hands at rest), or (T, 23, 3, 3) / (T, 21, 3, 3) matrices | |
| or pose / poses | (T, 72) | global_orient and body_pose in one |
| transl (or trans) | (T, 3) | SMPL's translation in the camera frame (m): the pelvis is at transl + J0 |
| betas | (10,) or (T, 10), optional | kept, not used: the humanoid is the mean shape |
| fps (or frame_rate) | scalar, optional | the video's rate (default 30, or `fps=`); resampled to 30 |

The camera frame is OpenCV's (x right, y down, z forward), the frame estimators such as ROMP,
4D-Humans, PyMAF, SMPLer-X or WHAM's camera-frame output use.

2D keypoints, in the same file or in `keypoints=` (an `.npz` / `.pkl` / `.json` with the fields
below, an OpenPose JSON file, or a directory of OpenPose's per-frame JSON files, sorted by name):
`keypoints_2d` (or keypoints, joints2d, pose_keypoints_2d) of shape (T, K, 3) with the confidence
last, or (T, K, 2) with `keypoint_confidence` (or scores, confidence) (T, K); pixels. K = 17 is
COCO-17, K = 25 is OpenPose BODY-25 (or say `keypoint_layout`: "coco17" / "body25"). Each layout's
joints map to the SMPL bodies (`LAYOUTS`); joints without a body (eyes, ears, heels, small toes)
are dropped, bodies without a joint get confidence 0. Approximations: COCO's and BODY-25's nose
stands for the SMPL Head joint (about 10 cm behind it), their hips for SMPL's hip joints, the big
toes for the toe bodies.

Camera intrinsics, in the same file or in `camera=` (an `.npz` / `.json` / dict): `K` (or
intrinsics, camera_intrinsics) (3, 3), or `focal_length` (a scalar, (2,), or per frame: the
median is taken) with `principal_point` (or camera_center, (2,); default the image centre); and
`image_size` (or img_size, resolution) (width, height), required. Optional extrinsics put the
estimate in the world: `camera_rotation` (3, 3, world -> camera) and `camera_position` (3,, the
camera centre, z-up world, metres). Without them the camera is taken as level (its image y axis
along the world's -z, looking along +x), and the floor is put under the estimate: at the 5th
percentile of its per-frame lowest point, so a few sunk frames still sink.

Anything missing, of the wrong shape, non-finite, or not matching in frame count raises
`EstimatorFileError` naming the file and the field. `export_estimator_output` writes a
`VideoInput` in this layout (camera-frame SMPL parameters, keypoints in a chosen layout,
intrinsics): what the tests and the example write instead of real data.
"""

from __future__ import annotations

import json
import pickle
import zipfile
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..humanoid.kinematics import forward_kinematics, lowest_point
from ..humanoid.skeleton import BODY_NAMES, MEAN_SKELETON, NUM_BODIES
from ..rotations import quat_from_matrix, quat_from_rotvec, quat_to_matrix, quat_to_rotvec
from .video_input import VideoInput
from .export import local_quat_to_smpl_pose
from .loaders import MotionFileError, _check, _check_fps, smpl_pose_to_local_quat
from .motion import FPS

COCO17 = ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
          "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
          "right_knee", "left_ankle", "right_ankle")
BODY25 = ("Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "MidHip", "RHip",
          "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar", "LBigToe", "LSmallToe",
          "LHeel", "RBigToe", "RSmallToe", "RHeel")
# Layout -> (joint names, {joint index: SMPL body name}).
LAYOUTS = {
    "coco17": (COCO17, {0: "Head", 5: "L_Shoulder", 6: "R_Shoulder", 7: "L_Elbow", 8: "R_Elbow", 9: "L_Wrist",
                        10: "R_Wrist", 11: "L_Hip", 12: "R_Hip", 13: "L_Knee", 14: "R_Knee", 15: "L_Ankle",
                        16: "R_Ankle"}),
    "body25": (BODY25, {0: "Head", 1: "Neck", 2: "R_Shoulder", 3: "R_Elbow", 4: "R_Wrist", 5: "L_Shoulder",
                        6: "L_Elbow", 7: "L_Wrist", 8: "Pelvis", 9: "R_Hip", 10: "R_Knee", 11: "R_Ankle",
                        12: "L_Hip", 13: "L_Knee", 14: "L_Ankle", 19: "L_Toe", 22: "R_Toe"}),
}
_LAYOUT_OF_K = {len(names): layout for layout, (names, _) in LAYOUTS.items()}
# The level camera assumed without extrinsics: image x = world -y, image y = world -z, optical axis = world +x.
LEVEL_CAMERA = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
FLOOR_PERCENTILE = 5.0

_ALIASES = {
    "transl": ("transl", "trans"),
    "fps": ("fps", "frame_rate", "framerate"),
    "keypoints": ("keypoints_2d", "keypoints", "joints2d", "pose_keypoints_2d"),
    "confidence": ("keypoint_confidence", "scores", "confidence"),
    "K": ("K", "intrinsics", "camera_intrinsics"),
    "principal_point": ("principal_point", "camera_center"),
    "image_size": ("image_size", "img_size", "resolution"),
}


class EstimatorFileError(MotionFileError):
    """An estimator output file that cannot be used: `path` and `reason` name the file and the field."""


# ---------------------------------------------------------------------- reading files
def _read_dict(path: Path) -> dict:
    """The top-level mapping of an .npz, .pkl or .json file."""
    if not path.exists():
        raise EstimatorFileError(path, "no such file")
    try:
        if path.suffix == ".npz":
            if not zipfile.is_zipfile(path):
                raise EstimatorFileError(path, "not a .npz file (no zip archive inside)")
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        if path.suffix == ".pkl":
            import joblib

            data = joblib.load(path)
        elif path.suffix == ".json":
            data = json.loads(path.read_text())
        else:
            raise EstimatorFileError(path, f"unknown file type {path.suffix!r}; expected .npz, .pkl or .json")
    except EstimatorFileError:
        raise
    except (OSError, ValueError, EOFError, pickle.UnpicklingError, KeyError, IndexError) as e:
        raise EstimatorFileError(path, f"not readable ({type(e).__name__}: {e})") from None
    if not isinstance(data, dict):
        raise EstimatorFileError(path, f"holds a {type(data).__name__}, expected a mapping of fields")
    return data


def _person(path: Path, data: dict, person) -> dict:
    """The one person's fields of a file that may hold {person id: fields} (VIBE, PHALP)."""
    nested = {k: v for k, v in data.items() if isinstance(v, dict)}
    if not nested or any(k in data for k in ("global_orient", "body_pose", "pose", "poses")):
        return data
    if person is None:
        if len(nested) > 1:
            raise EstimatorFileError(path, f"holds {len(nested)} people {sorted(map(str, nested))[:8]}; choose one "
                                           "with person=")
        return next(iter(nested.values()))
    for key in (person, str(person)):
        if key in nested:
            return nested[key]
    try:
        if int(person) in nested:
            return nested[int(person)]
    except (TypeError, ValueError):
        pass
    raise EstimatorFileError(path, f"no person {person!r}; it holds {sorted(map(str, nested))[:8]}")


def _field(data: dict, name: str):
    for key in _ALIASES.get(name, (name,)):
        if key in data:
            return key, data[key]
    return None, None


def _rotvecs(path: Path, name: str, value, joints: tuple[int, ...]) -> np.ndarray:
    """(T, J, 3) axis-angle rotations from axis-angle or rotation-matrix arrays of J in `joints`."""
    tails = [(3 * j,) for j in joints] + [(j, 3) for j in joints] + [(j, 3, 3) for j in joints]
    if joints == (1,):
        tails += [(3, 3)]
    arr = _check(path, name, value, *tails)
    t = len(arr)
    if arr.shape[-2:] == (3, 3) and arr.ndim in (3, 4):
        mats = arr.reshape(t, -1, 3, 3)
        det = np.linalg.det(mats)
        if not (np.allclose(mats @ mats.swapaxes(-1, -2), np.eye(3), atol=1e-3) and (det > 0).all()):
            raise EstimatorFileError(path, f"'{name}' holds matrices that are not rotations")
        return quat_to_rotvec(quat_from_matrix(mats))
    return arr.reshape(t, -1, 3)


def _smpl_pose(path: Path, data: dict) -> tuple[np.ndarray, str]:
    """(T, 24, 3) SMPL axis-angle pose in the camera frame (hands at rest where absent), and
    the name of the field the frame count comes from."""
    if "global_orient" in data or "body_pose" in data:
        for key in ("global_orient", "body_pose"):
            if key not in data:
                raise EstimatorFileError(path, f"has no '{key}' (SMPL parameters need global_orient and body_pose)")
        root = _rotvecs(path, "global_orient", data["global_orient"], (1,))
        body = _rotvecs(path, "body_pose", data["body_pose"], (23, 21))
        if len(root) != len(body):
            raise EstimatorFileError(path, f"'global_orient' has {len(root)} frames but 'body_pose' {len(body)}")
        pose = np.zeros((len(root), 24, 3))
        pose[:, :1], pose[:, 1:1 + body.shape[1]] = root, body
        return pose, "body_pose"
    for key in ("pose", "poses"):
        if key in data:
            arr = _check(path, key, data[key], (72,), (24, 3))
            return arr.reshape(len(arr), 24, 3), key
    raise EstimatorFileError(path, "has no SMPL pose: expected 'global_orient' and 'body_pose', or 'pose' (T, 72); "
                                   f"fields: {sorted(map(str, data))[:20]}")


def _keypoints(path: Path, data: dict, layout: str | None) -> tuple[np.ndarray, np.ndarray] | None:
    """(pixels (T, 24, 2), confidence (T, 24)) in BODY_NAMES order, or None without keypoints."""
    key, value = _field(data, "keypoints")
    if key is None:
        return None
    arr = np.asarray(value)
    if arr.ndim != 3 or arr.shape[-1] not in (2, 3):
        raise EstimatorFileError(path, f"'{key}' has shape {arr.shape}, expected (T, K, 3) with the confidence last, "
                                       "or (T, K, 2) with 'keypoint_confidence'")
    k = arr.shape[1]
    layout = layout or (str(np.asarray(data["keypoint_layout"]).item()) if "keypoint_layout" in data else None)
    layout = layout.lower() if layout else _LAYOUT_OF_K.get(k)
    if layout not in LAYOUTS:
        raise EstimatorFileError(path, f"'{key}' has {k} keypoints per frame; cannot tell the layout (known: "
                                       f"{', '.join(f'{n} ({len(LAYOUTS[n][0])})' for n in LAYOUTS)}): set "
                                       "keypoint_layout")
    names, mapping = LAYOUTS[layout]
    arr = _check(path, key, arr, (len(names), arr.shape[-1]))
    if arr.shape[-1] == 3:
        px, conf = arr[..., :2], arr[..., 2]
    else:
        ckey, cval = _field(data, "confidence")
        if ckey is None:
            raise EstimatorFileError(path, f"'{key}' has no confidences: give (T, K, 3) or 'keypoint_confidence' (T, K)")
        px, conf = arr, _check(path, ckey, cval, (len(names),))
        if len(conf) != len(px):
            raise EstimatorFileError(path, f"'{ckey}' has {len(conf)} frames but '{key}' {len(px)}")
    if (conf < 0).any() or (conf > 1.0 + 1e-6).any():
        raise EstimatorFileError(path, f"confidences of '{key}' must lie in [0, 1]")
    out_px, out_conf = np.zeros((len(px), NUM_BODIES, 2)), np.zeros((len(px), NUM_BODIES))
    for j, body in mapping.items():
        b = BODY_NAMES.index(body)
        out_px[:, b], out_conf[:, b] = px[:, j], conf[:, j].clip(0.0, 1.0)
    return out_px, out_conf


def read_openpose(path: str | Path, person: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(pixels (T, 24, 2), confidence (T, 24)) from OpenPose BODY-25 JSON: a directory of per-frame
    files (`*_keypoints.json`, sorted by name) or one file per frame. A frame without the person
    has confidence 0."""
    path = Path(path)
    files = sorted(path.glob("*.json")) if path.is_dir() else [path]
    if not files:
        raise EstimatorFileError(path, "no OpenPose .json files in this directory")
    frames = []
    for f in files:
        try:
            doc = json.loads(f.read_text())
        except (OSError, ValueError) as e:
            raise EstimatorFileError(f, f"not readable JSON ({e})") from None
        people = doc.get("people") if isinstance(doc, dict) else None
        if people is None:
            raise EstimatorFileError(f, "has no 'people' list (not OpenPose output)")
        if len(people) <= person:
            frames.append(np.zeros((len(BODY25), 3)))
            continue
        flat = np.asarray(people[person].get("pose_keypoints_2d", []), float)
        if flat.size != 3 * len(BODY25):
            raise EstimatorFileError(f, f"'pose_keypoints_2d' has {flat.size} numbers, expected {3 * len(BODY25)} "
                                        "(BODY-25: x, y, confidence per joint)")
        frames.append(flat.reshape(len(BODY25), 3))
    return _keypoints(files[0] if len(files) == 1 else path, {"keypoints_2d": np.stack(frames)}, "body25")


def _camera_fields(path: Path, data: dict, frames: int) -> dict | None:
    """fx, fy, cx, cy, width, height and optional extrinsics from a mapping, or None if it has
    no intrinsics at all."""
    kkey, k = _field(data, "K")
    fkey = "focal_length" if "focal_length" in data else None
    skey, size = _field(data, "image_size")
    if kkey is None and fkey is None:
        return None
    if skey is None:
        raise EstimatorFileError(path, "camera intrinsics need 'image_size' (width, height) in pixels")
    size = np.asarray(size, float).ravel()
    if size.shape != (2,) or not np.isfinite(size).all() or (size < 1).any():
        raise EstimatorFileError(path, f"'{skey}' must be (width, height) in pixels, got {size.tolist()}")
    width, height = int(size[0]), int(size[1])
    if kkey is not None:
        k = np.asarray(k, float)
        if k.shape != (3, 3) or not np.isfinite(k).all():
            raise EstimatorFileError(path, f"'{kkey}' must be a (3, 3) intrinsics matrix, got shape {k.shape}")
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    else:
        f = np.asarray(data[fkey], float)
        if f.ndim == 2 and f.shape[1] == 2:  # per frame (T, 2)
            f = np.median(f, 0)
        elif f.ndim == 1 and len(f) not in (1, 2):  # per frame (T,)
            f = np.median(f, keepdims=True)
        f = f.ravel()
        if f.size not in (1, 2) or not np.isfinite(f).all():
            raise EstimatorFileError(path, f"'focal_length' must be a number, (fx, fy) or one per frame, got shape "
                                           f"{np.shape(data[fkey])}")
        fx, fy = (f[0], f[0]) if f.size == 1 else (f[0], f[1])
        pkey, pp = _field(data, "principal_point")
        pp = np.array([width / 2, height / 2]) if pkey is None else np.asarray(pp, float).ravel()
        if pp.shape != (2,):
            raise EstimatorFileError(path, f"'{pkey}' must be (cx, cy) in pixels")
        cx, cy = pp
    if not (fx > 0 and fy > 0):
        raise EstimatorFileError(path, f"focal lengths must be positive, got fx={fx}, fy={fy}")
    out = dict(fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy), width=width, height=height)
    if "camera_rotation" in data or "camera_position" in data:
        for key in ("camera_rotation", "camera_position"):
            if key not in data:
                raise EstimatorFileError(path, f"extrinsics need both 'camera_rotation' and 'camera_position'; "
                                               f"'{key}' is missing")
        rot, pos = np.asarray(data["camera_rotation"], float), np.asarray(data["camera_position"], float).ravel()
        if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-4) or np.linalg.det(rot) < 0:
            raise EstimatorFileError(path, "'camera_rotation' must be a (3, 3) rotation matrix (world -> camera)")
        if pos.shape != (3,) or not np.isfinite(pos).all():
            raise EstimatorFileError(path, "'camera_position' must be 3 finite numbers (m)")
        out.update(rotation=rot, position=pos)
    return out


# ---------------------------------------------------------------------- the loader
def load_estimator_output(smpl: str | Path, keypoints: str | Path | None = None, camera: str | Path | dict | None = None,
                          *, fps: float | None = None, person=None, keypoint_layout: str | None = None,
                          name: str | None = None) -> VideoInput:
    """A `VideoInput` (no ground truth) from an estimator's files (module docstring). `fps`
    overrides a rate the file lacks (a rate in the file wins only when `fps` is None)."""
    try:
        return _load(Path(smpl), keypoints, camera, fps, person, keypoint_layout, name)
    except EstimatorFileError:
        raise
    except MotionFileError as e:  # the shared array checks: the same file and field, this module's error
        raise EstimatorFileError(e.path, e.reason) from None


def _load(smpl: Path, keypoints, camera, fps, person, keypoint_layout, name) -> VideoInput:
    data = _person(smpl, _read_dict(smpl), person)
    pose, pose_key = _smpl_pose(smpl, data)
    t = len(pose)
    tkey, transl = _field(data, "transl")
    if tkey is None:
        raise EstimatorFileError(smpl, "has no 'transl' (SMPL's translation in the camera frame, (T, 3)); weak-"
                                       "perspective cameras (VIBE's pred_cam) need converting first")
    transl = _check(smpl, tkey, transl, (3,))
    if len(transl) != t:
        raise EstimatorFileError(smpl, f"'{tkey}' has {len(transl)} frames but '{pose_key}' {t}")
    fkey, file_fps = _field(data, "fps")
    rate = float(fps) if fps is not None else (_check_fps(smpl, file_fps) if fkey is not None else FPS)

    # Keypoints: from their own file, else from the SMPL file.
    if keypoints is not None:
        kp_path = Path(keypoints)
        if kp_path.is_dir() or (kp_path.suffix == ".json" and _is_openpose(kp_path)):
            kp = read_openpose(kp_path)
        else:
            kp = _keypoints(kp_path, _person(kp_path, _read_dict(kp_path), person), keypoint_layout)
            if kp is None:
                raise EstimatorFileError(kp_path, "has no 2D keypoints ('keypoints_2d' (T, K, 3))")
    else:
        kp_path = smpl
        kp = _keypoints(smpl, data, keypoint_layout)
        if kp is None:
            raise EstimatorFileError(smpl, "has no 2D keypoints ('keypoints_2d' (T, K, 3)) and no keypoints= file "
                                           "was given")
    if len(kp[0]) != t:
        raise EstimatorFileError(kp_path, f"has {len(kp[0])} frames of keypoints but {smpl} has {t} of SMPL parameters")

    # Camera: its own file or dict, else the SMPL file.
    if camera is not None:
        cam_path = Path("<camera dict>") if isinstance(camera, dict) else Path(camera)
        cam = _camera_fields(cam_path, camera if isinstance(camera, dict) else _read_dict(cam_path), t)
    else:
        cam_path, cam = smpl, _camera_fields(smpl, data, t)
    if cam is None:
        raise EstimatorFileError(cam_path, "has no camera intrinsics ('K' (3, 3), or 'focal_length' with "
                                           "'image_size')")
    video = _to_world(pose, transl, cam, rate, name or smpl.stem, str(smpl), *kp)
    return video


def _is_openpose(path: Path) -> bool:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and "people" in doc


def _to_world(pose_cam: np.ndarray, transl: np.ndarray, cam: dict, fps: float, name: str, source: str,
              pixels: np.ndarray, conf: np.ndarray) -> VideoInput:
    """Camera-frame SMPL parameters -> the estimate in the suite's world frame (module docstring)."""
    extrinsic = "rotation" in cam
    rot = cam["rotation"] if extrinsic else LEVEL_CAMERA
    pos = cam["position"] if extrinsic else np.zeros(3)
    # World from camera: X_w = R^T X_c + C; the root's rotation G_w = R^T G_c.
    g_cam = quat_to_matrix(quat_from_rotvec(pose_cam[:, 0]))
    pose = pose_cam.copy()
    pose[:, 0] = quat_to_rotvec(quat_from_matrix(rot.T @ g_cam))
    local = smpl_pose_to_local_quat(pose)
    pelvis = (transl + MEAN_SKELETON.pelvis_smpl) @ rot + pos
    if not extrinsic:
        body_pos, body_quat = forward_kinematics(pelvis, local, MEAN_SKELETON.offsets)
        floor = np.percentile(lowest_point(body_pos, body_quat, MEAN_SKELETON), FLOOR_PERCENTILE)
        pelvis = pelvis - np.array([0.0, 0.0, floor])
        pos = pos - np.array([0.0, 0.0, floor])
    camera = Camera(cam["fx"], cam["fy"], cam["cx"], cam["cy"], cam["width"], cam["height"], rot, pos)
    return VideoInput(name, fps, pelvis, local, pixels, conf, camera, None, source=source)


# ---------------------------------------------------------------------- writing (tests, the example)
def export_estimator_output(video: VideoInput, path: str | Path, *, layout: str = "body25", extrinsics: bool = True,
                            matrices: bool = False) -> Path:
    """Write `video` as an estimator would (module docstring): camera-frame SMPL parameters
    (axis-angle, or rotation matrices with `matrices`), keypoints in `layout` with confidences,
    intrinsics, fps, and the camera's extrinsics unless `extrinsics=False`. `.npz` or `.pkl`."""
    path = Path(path)
    cam = video.camera
    pose = local_quat_to_smpl_pose(video.local_quat).reshape(video.num_frames, 24, 3)
    g_world = quat_to_matrix(quat_from_rotvec(pose[:, 0]))
    pose[:, 0] = quat_to_rotvec(quat_from_matrix(cam.rotation @ g_world))
    transl = cam.to_camera(video.root_pos) - MEAN_SKELETON.pelvis_smpl
    names, mapping = LAYOUTS[layout]
    kp = np.zeros((video.num_frames, len(names), 3))
    for j, body in mapping.items():
        b = BODY_NAMES.index(body)
        kp[:, j, :2], kp[:, j, 2] = video.keypoints[:, b], video.confidence[:, b]
    if matrices:
        mats = quat_to_matrix(quat_from_rotvec(pose))
        fields = {"global_orient": mats[:, :1], "body_pose": mats[:, 1:]}
    else:
        fields = {"global_orient": pose[:, 0], "body_pose": pose[:, 1:].reshape(len(pose), 69)}
    fields.update(transl=transl, betas=np.zeros(10), keypoints_2d=kp, keypoint_layout=layout, fps=video.fps,
                  focal_length=cam.focal, principal_point=cam.principal_point,
                  image_size=np.array([cam.width, cam.height]))
    if extrinsics:
        fields.update(camera_rotation=cam.rotation, camera_position=cam.position)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".npz":
        np.savez(path, **fields)
    elif path.suffix == ".pkl":
        import joblib

        joblib.dump(fields, path)
    else:
        raise ValueError(f"export_estimator_output writes .npz or .pkl, got {path.suffix!r}")
    return path


def write_openpose(video: VideoInput, directory: str | Path) -> Path:
    """`video`'s keypoints as OpenPose BODY-25 per-frame JSON files in `directory`."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    names, mapping = LAYOUTS["body25"]
    for t in range(video.num_frames):
        kp = np.zeros((len(names), 3))
        for j, body in mapping.items():
            b = BODY_NAMES.index(body)
            kp[j, :2], kp[j, 2] = video.keypoints[t, b], video.confidence[t, b]
        doc = {"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": kp.ravel().tolist()}]}
        (directory / f"{video.name}_{t:012d}_keypoints.json").write_text(json.dumps(doc))
    return directory


__all__ = ["load_estimator_output", "read_openpose", "export_estimator_output", "write_openpose", "EstimatorFileError",
           "LAYOUTS", "COCO17", "BODY25"]
