"""Calibrated pinhole cameras: projection of world points to pixels, its Jacobian, and random
plausible cameras around a motion (for generated video input, `smpl_envs.motion.estimator_noise`).

Conventions: the suite's world frame (z up, metres); the camera frame is OpenCV's (x right,
y down, z forward along the optical axis). A camera is its intrinsics (focal lengths fx, fy and
principal point cx, cy in pixels, image width and height) and its extrinsics: `rotation` R
(world -> camera, rows are the camera axes in world coordinates) and `position` C (the camera
centre in the world). A world point X is at X_c = R (X - C) in the camera frame and projects to

    u = fx x_c / z_c + cx,    v = fy y_c / z_c + cy.

"Normalised" image coordinates are ((u - cx) / fx, (v - cy) / fy) = (x_c / z_c, y_c / z_c): the
projection with the intrinsics divided out, what the policies of the video task see.

The array functions (`to_camera`, `project_normalized`, `normalized_jacobian`) take NumPy arrays
or torch tensors alike (only operators both share), so the refinement unit of `agents.simpoe`
projects with the same code as the environment.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .features import xp

MIN_DEPTH = 1e-2  # m: depth below which a point counts as behind the camera (its projection is clamped)


# ---------------------------------------------------------------------- array functions (NumPy or torch)
def to_camera(points, rotation, position):
    """Points (..., K, 3) in the camera frame(s) (..., 3, 3) / (..., 3): R (X - C)."""
    return (points - position[..., None, :]) @ rotation.swapaxes(-1, -2)


def project_normalized(points_cam):
    """(..., 2) normalised image coordinates (x / z, y / z) of camera-frame points (..., 3); depths
    below MIN_DEPTH are clamped to it (such points are invisible; callers give them no weight)."""
    z = points_cam[..., 2:3].clip(MIN_DEPTH, None)
    return points_cam[..., :2] / z


def normalized_jacobian(points_cam):
    """(..., 2, 3) derivative of `project_normalized` with respect to the camera-frame point:
    [[1/z, 0, -x/z^2], [0, 1/z, -y/z^2]] (depth clamped as there)."""
    x, y = points_cam[..., 0], points_cam[..., 1]
    z = points_cam[..., 2].clip(MIN_DEPTH, None)
    inv = 1.0 / z
    zero = 0.0 * x
    row0 = [inv, zero, -x * inv * inv]
    row1 = [zero, inv, -y * inv * inv]
    m = xp(points_cam)
    return m.stack([m.stack(row0, -1), m.stack(row1, -1)], -2)


def look_at_rotation(eye, target, up=(0.0, 0.0, 1.0), roll: float = 0.0) -> np.ndarray:
    """World -> camera rotation of a camera at `eye` looking at `target` with the world's `up`
    pointing up in the image (OpenCV axes), turned by `roll` radians about its optical axis."""
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)  # right: forward x up (the image's y points down)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at_rotation: the viewing direction is parallel to `up`")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    return np.stack([x, y, z])


# ---------------------------------------------------------------------- the camera
@dataclass(frozen=True)
class Camera:
    """A calibrated pinhole camera (module docstring). Arrays are float64."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    rotation: np.ndarray  # (3, 3) world -> camera
    position: np.ndarray  # (3,) camera centre, world

    def __post_init__(self):
        rot = np.asarray(self.rotation, float)
        pos = np.asarray(self.position, float)
        if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-5) or np.linalg.det(rot) < 0:
            raise ValueError(f"camera rotation must be a (3, 3) rotation matrix, got {np.asarray(self.rotation)!r}")
        if pos.shape != (3,) or not np.isfinite(pos).all():
            raise ValueError(f"camera position must be 3 finite numbers, got {np.asarray(self.position)!r}")
        for name in ("fx", "fy"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"camera {name} must be a positive focal length in pixels, got {v!r}")
        for name in ("width", "height"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"camera {name} must be a positive image size in pixels")
        object.__setattr__(self, "rotation", rot)
        object.__setattr__(self, "position", pos)

    @property
    def intrinsics(self) -> np.ndarray:
        """K (3, 3)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def focal(self) -> np.ndarray:
        return np.array([self.fx, self.fy])

    @property
    def principal_point(self) -> np.ndarray:
        return np.array([self.cx, self.cy])

    def to_camera(self, points) -> np.ndarray:
        """World points (..., 3) in the camera frame."""
        p = np.asarray(points, float)
        return (p - self.position) @ self.rotation.T

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """(pixels (..., 2), depths (...)) of world points (..., 3)."""
        pc = self.to_camera(points)
        return project_normalized(pc) * self.focal + self.principal_point, pc[..., 2]

    def jacobian(self, points) -> np.ndarray:
        """(..., 2, 3) derivative of the pixel coordinates with respect to the world point."""
        pc = self.to_camera(points)
        return (normalized_jacobian(pc) * self.focal[:, None]) @ self.rotation

    def backproject(self, pixels, depths) -> np.ndarray:
        """World points (..., 3) at camera depths `depths` (...) along the rays of `pixels` (..., 2):
        the inverse of `project`."""
        xy = self.normalize(pixels) * np.asarray(depths, float)[..., None]
        pc = np.concatenate([xy, np.asarray(depths, float)[..., None]], -1)
        return pc @ self.rotation + self.position

    def normalize(self, pixels) -> np.ndarray:
        """Normalised image coordinates of pixels (..., 2)."""
        return (np.asarray(pixels, float) - self.principal_point) / self.focal

    def visible(self, pixels, depths) -> np.ndarray:
        """(...) whether a projection lies in front of the camera and inside the image."""
        u, v = pixels[..., 0], pixels[..., 1]
        return (depths > 0.1) & (u >= 0) & (u < self.width) & (v >= 0) & (v < self.height)

    def moved(self, rotation, position) -> "Camera":
        return replace(self, rotation=rotation, position=position)

    def to_dict(self) -> dict:
        return {"fx": float(self.fx), "fy": float(self.fy), "cx": float(self.cx), "cy": float(self.cy),
                "width": int(self.width), "height": int(self.height), "rotation": self.rotation.tolist(),
                "position": self.position.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        return cls(d["fx"], d["fy"], d["cx"], d["cy"], int(d["width"]), int(d["height"]),
                   np.asarray(d["rotation"], float), np.asarray(d["position"], float))

    @classmethod
    def look_at(cls, eye, target, *, fx: float, width: int = 1280, height: int = 720, fy: float | None = None,
                cx: float | None = None, cy: float | None = None, roll: float = 0.0) -> "Camera":
        return cls(fx, fx if fy is None else fy, width / 2 if cx is None else cx, height / 2 if cy is None else cy,
                   width, height, look_at_rotation(eye, target, roll=roll), np.asarray(eye, float))


# ---------------------------------------------------------------------- random plausible cameras
# Where a generated camera may stand, as a person filming another would place it.
CAMERA_DISTANCE = (3.5, 6.0)    # m from the motion's centre, plus the motion's horizontal radius
CAMERA_HEIGHT = (0.8, 1.8)      # m
CAMERA_HFOV_DEG = (45.0, 65.0)  # horizontal field of view
CAMERA_ROLL_DEG = 2.0           # std of the roll about the optical axis
IMAGE_SIZES = ((1280, 720), (1920, 1080))
MIN_VISIBLE = 0.9               # share of the pelvis frames that must lie inside the image


def random_camera(rng: np.random.Generator, body_pos: np.ndarray, tries: int = 20) -> Camera:
    """A random static camera that films the motion `body_pos` (T, 24, 3): placed around the
    motion at a distance and height a person would film from, looking at it, with a field of view
    and image size of common video cameras (the ranges above), so that the pelvis stays in the
    image in at least MIN_VISIBLE of the frames and every body lies in front of the camera. Draws
    again (farther away) up to `tries` times; the last draw is returned regardless."""
    body_pos = np.asarray(body_pos, float)
    pelvis = body_pos[:, 0]
    centre = pelvis[:, :2].mean(0)
    radius = float(np.linalg.norm(pelvis[:, :2] - centre, axis=-1).max())
    cam = None
    for attempt in range(tries):
        width, height = IMAGE_SIZES[int(rng.integers(len(IMAGE_SIZES)))]
        hfov = np.deg2rad(rng.uniform(*CAMERA_HFOV_DEG))
        fx = 0.5 * width / np.tan(0.5 * hfov)
        dist = rng.uniform(*CAMERA_DISTANCE) * (1.0 + 0.25 * attempt) + radius
        azimuth = rng.uniform(-np.pi, np.pi)
        eye = np.array([centre[0] + dist * np.cos(azimuth), centre[1] + dist * np.sin(azimuth),
                        rng.uniform(*CAMERA_HEIGHT)])
        target = np.array([centre[0], centre[1], rng.uniform(0.7, 1.1)])
        cx, cy = width / 2 * (1 + rng.uniform(-0.01, 0.01)), height / 2 * (1 + rng.uniform(-0.01, 0.01))
        cam = Camera.look_at(eye, target, fx=fx, width=width, height=height, cx=cx, cy=cy,
                             roll=np.deg2rad(rng.normal(0.0, CAMERA_ROLL_DEG)))
        px, depth = cam.project(body_pos)
        if (depth > 0.5).all() and cam.visible(px[:, 0], depth[:, 0]).mean() >= MIN_VISIBLE:
            return cam
    return cam


__all__ = ["Camera", "random_camera", "to_camera", "project_normalized", "normalized_jacobian", "look_at_rotation",
           "MIN_DEPTH"]
