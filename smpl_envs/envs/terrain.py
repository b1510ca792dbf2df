"""`SMPL/Terrain-v0`: follow a 2D path across procedural terrain (REFERENCE.md sections 5 and 8,
PULSE's pedestrian terrain).

The terrain (`smpl_envs.terrain`) is a MuJoCo heightfield added to the model before compiling:
`terrain_size` (4 x 4) tiles of `tile_size` (20) m, 0.1 m apart, of smooth slopes, rough slopes,
stairs up and down, discrete obstacles, poles and flat ground at PULSE's shares, each with its own
difficulty, inside a flat 10 m border. The same `terrain_seed` builds the same terrain.
`terrain="flat"` gives the builder's plain floor and no heightfield. With a heightfield the
builder's floor plane is lowered to the heightfield's base, below every terrain sample, so the two
never touch.

Every world holds the whole terrain. A reset puts a world on the flat centre platform of a random
tile (within +-1 m of its centre; poles keep 2 m clear of it), lifted so that the lowest point of
its start pose (a clip frame of `motions=` or the rest pose) clears the highest terrain within
0.3 m of any body, and draws its path: 101 vertices 0.1 s apart (10 s) from the pelvis; heading
U(-pi, pi), turning U(-0.2, 0.2) rad per vertex, with a sharp turn U(-pi, pi) at p 0.02; speed
U(0, 3) m/s changing U(-0.2, 0.2) per vertex, clipped to [0, 3]. Vertices stay 1 m inside the
terrain's edge (clamped).

Observation (float32, heading frame):

| slice | size | content |
|---|---|---|
| 0:358 | 358 | self observation; its root height is the pelvis' height above the terrain under it |
| 358:378 | 20 | the path 0.5, 1.0, ..., 5.0 s ahead, xy relative to the pelvis (m) |
| 378:1402 | 1024 | height map: 32 x 32 samples over +-2 m around the pelvis, heading-aligned (row i: forward offset, column j: leftward offset, both linspace(-2, 2, 32)), each clip(h_pelvis - h, -3, 3) x 5 |

The height map is one batched bilinear lookup into the height grid for every world and sample.

Reward (one term, `info["reward_path"]`): exp(-2 ||xy error||^2), the pelvis against the path's
point at the current time.

Episode: 300 steps (10 s). Terminates on a fall, measured from the terrain: a body other than
the feet less than `fall_height` (0.15 m) above the lowest terrain sample around it, or the head
less than 0.3 m above it; or when the pelvis is more than `off_path_distance` (4 m) from the
path's current point.

`info`: `path_error` (m), `path_point` (world xy of the current point), `path_length` (m of path
from its start to the current point), `start_tile` (row-major tile index of the start), plus the
core's entries.

Backends: "cpu" (NumPy) and "warp" (`backend="warp", device=...`: MuJoCo Warp, torch tensors on
the device, float32), one code path: the terrain is built on the host once and its height grids,
tile centres and the map's offsets are copied to the device at construction; paths, lookups,
observation, reward, termination, info and start placement then run on the backend's arrays
(random draws through `smpl_envs.backend`, so the CPU backend's episodes are those it always had).
MuJoCo Warp's heightfield collisions make other contact points than CPU MuJoCo's, so on the
terrain the two backends' physics part by ~1e-2 m within a step; the task's reads of one state
agree to float32 rounding (tests/test_terrain.py).

Evaluation (`smpl_envs.evaluate`, `smpl-envs eval`): 32 seeded episodes; the mean xy error to the
path, the distance along the path reached (the path length at the last step within 1 m of it),
the fraction of episodes without a fall or leaving the path, and the score (mean reward per step
over 10 s).
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..backend import NumpyBackend
from ..evaluation import EpisodeProtocol
from ..features import self_obs, xp
from ..humanoid.builder import FRICTION
from ..humanoid.kinematics import forward_kinematics, lowest_point
from ..humanoid.skeleton import BODY_NAMES, MEAN_SKELETON
from ..terrain import cell_index, lookup, make_terrain
from .base import FEET
from .goal import GoalVecEnv

PATH_VERTICES = 101
PATH_DT = 0.1            # s between path vertices
PATH_AHEAD = 10          # observed future points ...
PATH_AHEAD_DT = 0.5      # ... this far apart (s)
MAP_SIZE = 32            # height map samples per side ...
MAP_HALF = 2.0           # ... over +-2 m
MAP_CLIP, MAP_SCALE = 3.0, 5.0
FOLLOWED = 1.0           # m: within this of the path counts as following it (evaluation)
SPAWN_JITTER = 1.0       # m around a tile centre, inside its 3 x 3 m platform
EDGE_MARGIN = 1.0        # m: path vertices stay this far inside the terrain
LIFT_MARGIN = 0.005      # m of air under a start pose's lowest point
HEAD = BODY_NAMES.index("Head")
TERRAIN_LAYOUT = (
    ("path", 2 * PATH_AHEAD, "the path 0.5-5 s ahead, xy relative to the pelvis, heading frame (m)"),
    ("height_map", MAP_SIZE * MAP_SIZE, "clip(h_pelvis - h, -3, 3) x 5 on a 32 x 32 grid over +-2 m"),
)
_ticks = np.linspace(-MAP_HALF, MAP_HALF, MAP_SIZE)
MAP_OFFSETS = np.stack(np.meshgrid(_ticks, _ticks, indexing="ij"), -1).reshape(-1, 2)  # (1024, 2) forward, left

# The functions below take NumPy arrays or torch tensors (the warp backend's) alike.


def path_reward(root_xy, point):
    """(reward (N,), xy error (N,)) of pelvis positions against path points (N, 2)."""
    m = xp(root_xy, point)
    d = root_xy - point
    sq = (d * d).sum(-1)
    return m.exp(-2.0 * sq), m.sqrt(sq)


def make_paths(start_xy, rng: np.random.Generator, bounds=None, backend=None):
    """(N, 101, 2) paths from start points (N, 2) as REFERENCE section 8 draws them, and their
    (N, 101) arc lengths; `bounds` (x_min, x_max, y_min, y_max) clamps the vertices. Draws go
    through `backend` (`smpl_envs.backend`; NumPy by default) with the generator `rng`."""
    b = backend or NumpyBackend()
    m = b.xp
    n = len(start_xy)
    steps = PATH_VERTICES - 1
    turn = b.uniform(rng, (n, steps), -0.2, 0.2)
    sharp = b.uniform(rng, (n, steps)) < 0.02
    turn = m.where(sharp, b.uniform(rng, (n, steps), -np.pi, np.pi), turn)
    zero = m.zeros_like(turn[:, :1])
    heading = b.uniform(rng, n, -np.pi, np.pi)[:, None] + m.concatenate([zero, m.cumsum(turn, 1)[:, :-1]], 1)
    speed = [b.uniform(rng, n, 0.0, 3.0)]
    change = b.uniform(rng, (n, steps), -0.2, 0.2)
    for k in range(1, steps):  # the clip makes each speed depend on the last: a loop over vertices
        speed.append((speed[-1] + change[:, k]).clip(0.0, 3.0))
    moves = (m.stack(speed, 1) * PATH_DT)[..., None] * m.stack([m.cos(heading), m.sin(heading)], -1)
    path = start_xy[:, None] + m.concatenate([m.zeros_like(moves[:, :1]), m.cumsum(moves, 1)], 1)
    if bounds is not None:
        x0, x1, y0, y1 = bounds
        path[..., 0] = path[..., 0].clip(x0 + EDGE_MARGIN, x1 - EDGE_MARGIN)
        path[..., 1] = path[..., 1].clip(y0 + EDGE_MARGIN, y1 - EDGE_MARGIN)
    d = path[:, 1:] - path[:, :-1]
    seg = m.sqrt((d * d).sum(axis=-1))  # np.linalg.norm's own sum: the same bits
    # Drawn and summed in float64 on either backend, returned in the backend's float.
    return b.asarray(path), b.asarray(m.concatenate([m.zeros_like(seg[:, :1]), m.cumsum(seg, 1)], 1))


def _arange(n: int, like):
    m = xp(like)
    return np.arange(n) if m is np else m.arange(n, device=like.device)


def path_at(path, times):
    """Points (N, K, 2) of paths (N, 101, 2) at times (N, K) s, linear between vertices, held at
    the ends."""
    pos = (times / PATH_DT).clip(0.0, PATH_VERTICES - 1.000001)
    i = cell_index(pos).clip(max=PATH_VERTICES - 2)  # the bound above rounds up in float32
    f = (pos - i)[..., None]
    rows = _arange(len(path), path)[:, None]
    return path[rows, i] + f * (path[rows, i + 1] - path[rows, i])


def map_points(root_pos, heading, offsets=MAP_OFFSETS):
    """(N, 1024, 2) world xy of the height map's samples around pelvis positions (N, 3), aligned
    with headings (N, 3, 3); `offsets` (1024, 2): MAP_OFFSETS (as an array of the backend's)."""
    c, s = heading[:, 0, 0:1], heading[:, 1, 0:1]
    fx, fy = offsets[:, 0], offsets[:, 1]
    return xp(root_pos).stack([root_pos[:, :1] + c * fx - s * fy, root_pos[:, 1:2] + s * fx + c * fy], -1)


def map_obs(root_pos, ground):
    """(N, 1024) height map observation from the terrain heights (N, 1024) at `map_points`."""
    return (root_pos[:, 2:3] - ground).clip(-MAP_CLIP, MAP_CLIP) * MAP_SCALE


def height_map(terrain, root_pos, heading):
    """(N, 1024) height map observation of `terrain` (a `smpl_envs.terrain.Terrain`, or None for
    the flat floor) around pelvis positions (N, 3), aligned with headings (N, 3, 3): every world's
    1024 sample points rotated and moved at once, then one batched bilinear lookup."""
    xy = map_points(root_pos, heading)
    return map_obs(root_pos, np.zeros(xy.shape[:-1]) if terrain is None else terrain.height(xy))


def terrain_episode_metrics(log: dict) -> dict:
    error, length = log["path_error"], log["path_length"]
    followed = error <= FOLLOWED
    return {"path_error": float(error.mean()),
            "distance_m": float(length[followed][-1]) if followed.any() else 0.0}


class TerrainVecEnv(GoalVecEnv):
    """`gym.make_vec("SMPL/Terrain-v0", num_envs=N, **kwargs)`.

    kwargs: terrain ("mixed": PULSE's shares; "flat": no heightfield; a type name, a list of type
    names or a {type: share} mapping summing to 1; types in `smpl_envs.terrain.TERRAIN_TYPES`),
    terrain_difficulty ("levels": row r of tiles at r / rows; a number in [0, 1]; or a (min, max)
    range drawn per tile), terrain_size ((4, 4) rows x columns of tiles), tile_size (20 m),
    terrain_border (10 m), terrain_seed (0), off_path_distance (4 m), and GoalVecEnv's
    (fall_height, head_height, motions, start, ...).
    """

    task_layout = {"task": TERRAIN_LAYOUT}
    evaluation = EpisodeProtocol(("path_error", "path_length"), terrain_episode_metrics)
    backends = ("cpu", "warp")

    def __init__(self, num_envs: int = 1, *, terrain="mixed", terrain_difficulty="levels", terrain_size=(4, 4),
                 tile_size: float = 20.0, terrain_border: float = 10.0, terrain_seed: int = 0,
                 off_path_distance: float = 4.0, **kwargs):
        if not (isinstance(off_path_distance, (int, float, np.number)) and float(off_path_distance) > 0):
            raise ValueError(f"off_path_distance must be a positive distance in metres, got {off_path_distance!r}")
        self.off_path_distance = float(off_path_distance)
        self.terrain = None if (isinstance(terrain, str) and terrain == "flat") else make_terrain(
            terrain, terrain_difficulty, terrain_size, tile_size, terrain_border, terrain_seed)
        super().__init__(num_envs, **kwargs)
        n, b = self.num_envs, self.backend
        self.path = b.zeros((n, PATH_VERTICES, 2))
        self.path_length = b.zeros((n, PATH_VERTICES))
        self.start_tile = b.zeros(n, "int")
        self._points = b.zeros((n, 1 + PATH_AHEAD, 2))  # the path now and ahead, this step
        # Host tables on the backend, once (the NumPy backend keeps the very arrays): the height
        # grids and tile centres, the map's sample offsets, the path's observed times ...
        if self.terrain is not None:
            t = self.terrain
            self._heights, self._dilated, self._centres = b.asarray(t.heights), b.asarray(t.dilated), b.asarray(t.centres)
        self._map_offsets = b.asarray(MAP_OFFSETS)
        self._ahead = b.asarray(PATH_AHEAD_DT * np.arange(1 + PATH_AHEAD))
        # ... the rest pose's bodies (pelvis at its standing height), for lifting rest-pose
        # starts, and the collision geometry's support points (`lowest_point`).
        ident = np.tile([1.0, 0.0, 0.0, 0.0], (1, len(BODY_NAMES), 1))
        rest = forward_kinematics(self.model.qpos0[self.humanoid.qpos][None, :3], ident, MEAN_SKELETON.offsets)
        self._rest = tuple(b.asarray(x[0]) for x in rest)
        self._support = tuple(b.asarray(x) for x in MEAN_SKELETON.support_points())

    # ------------------------------------------------------------------ model
    def _configure(self, spec):
        t = self.terrain
        if t is None:
            return
        h = t.heights
        low, span = float(h.min()), float(h.max() - h.min())
        base = 1.0  # m of solid heightfield below its lowest sample
        x0, x1, y0, y1 = t.extent
        spec.add_hfield(name="terrain", nrow=h.shape[0], ncol=h.shape[1],
                        size=[(x1 - x0) / 2, (y1 - y0) / 2, max(span, 1e-3), base],
                        userdata=((h - low) / max(span, 1e-3)).ravel().tolist())
        # A plain material: the light's shading, not a texture, shows the slopes and steps.
        spec.add_material(name="terrain", rgba=[0.62, 0.58, 0.5, 1.0], specular=0.1, shininess=0.1)
        spec.worldbody.add_geom(name="terrain", type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname="terrain",
                                pos=[(x0 + x1) / 2, (y0 + y1) / 2, low], material="terrain",
                                friction=FRICTION, condim=3)
        # The builder's floor would cut through the terrain's pits: lower it under the heightfield.
        floor = spec.geom("floor")
        floor.pos = [0.0, 0.0, low - base]
        # Software (EGL/OSMesa) renderers draw the heightfield's millions of triangles once more
        # for the sun's shadow map; without it a frame costs less than half (measured: 0.28 s
        # against 0.67 s for 4 x 4 tiles). The headlight still shades the slopes and steps.
        spec.light("sun").castshadow = False

    # ------------------------------------------------------------------ terrain reads
    def ground(self, xy, mode: str = "bilinear"):
        """Terrain heights (...) at world xy (..., 2) (zeros on the flat floor), arrays of the
        env's backend; `mode` as `smpl_envs.terrain.Terrain.height`."""
        if self.terrain is None:
            return self.backend.zeros(tuple(xy.shape[:-1]))
        t = self.terrain
        if mode == "dilated":  # the highest terrain within 0.3 m of the point
            return lookup(self._dilated, xy, t.x0, t.y0, "max")
        return lookup(self._heights, xy, t.x0, t.y0, mode)

    def height_map(self, root_pos, heading):
        """(N, 1024) observation of the terrain around pelvis positions (N, 3), heading-aligned."""
        return map_obs(root_pos, self.ground(map_points(root_pos, heading, self._map_offsets)))

    # ------------------------------------------------------------------ episodes
    def _reset_task(self, ids, options):
        qpos, qvel = super()._reset_task(ids, options)  # pelvis over the origin
        b, rng, n = self.backend, self.np_random, len(ids)
        if self.terrain is None:
            spawn = b.zeros((n, 2))
            self.start_tile[ids] = 0
        else:
            tile = b.integers(rng, 0, len(self._centres), n)
            self.start_tile[ids] = tile
            spawn = b.asarray(self._centres[tile] + b.uniform(rng, (n, 2), -SPAWN_JITTER, SPAWN_JITTER))
        root = self.humanoid.qpos.start
        # The start pose's bodies, as it would stand on z = 0 over the spawn point.
        if self.motion_lib is None:
            pos, quat = b.rows(self._rest[0], n), b.rows(self._rest[1], n)
        else:
            frames = self.start_frame[ids]
            pos, quat = self.motion_frames.body_pos[frames], self.motion_frames.body_quat[frames]
        pos = b.copy(pos)
        pos[..., :2] += (spawn - pos[:, 0, :2])[:, None]
        # Lift: the pose's lowest point above the highest terrain within 0.3 m of any body.
        top = b.xp.amax(self.ground(pos[..., :2], "dilated"), -1)
        lift = top - lowest_point(pos, quat, MEAN_SKELETON, self._support).clip(max=0.0) + LIFT_MARGIN
        qpos[:, root:root + 2] = spawn
        qpos[:, root + 2] += lift
        bounds = None if self.terrain is None else self.terrain.extent
        self.path[ids], self.path_length[ids] = make_paths(spawn, rng, bounds, b)
        self._refresh_points(ids)
        return qpos, qvel

    def _refresh_points(self, ids=None):
        """The path's points now and 0.5-5 s ahead, from each world's clock."""
        ids = self.backend.arange(self.num_envs) if ids is None else ids
        t = self.elapsed[ids, None] / 30.0 + self._ahead
        self._points[ids] = path_at(self.path[ids], t)

    def _advance(self, active):
        self._refresh_points(None if active is None else self.backend.nonzero(active))

    def _fallen(self, body):
        # Heights above the lowest sample around each body, so a hand beside a pole or a step's
        # edge is not read as lying on it.
        z = body.pos[..., 2] - self.ground(body.pos[..., :2], "min")
        low = z < self.fall_height
        low[:, FEET] = False
        return low.any(-1) | (z[:, HEAD] < self.head_height)

    def _evaluate(self, body, heading):
        reward, error = path_reward(body.pos[:, 0, :2], self._points[:, 0])
        terminated = self._fallen(body) | (error > self.off_path_distance)
        return reward, {"path": reward}, terminated, self.backend.zeros(self.num_envs, "bool")

    def _observe(self, body, heading):
        m = self.backend.xp
        root = body.pos[:, 0]
        obs = self_obs(body, heading)
        obs[:, 0] = root[:, 2] - self.ground(root[:, :2])
        c, s = heading[:, 0, 0:1], heading[:, 1, 0:1]
        d = self._points[:, 1:] - root[:, None, :2]
        ahead = m.stack([c * d[..., 0] + s * d[..., 1], c * d[..., 1] - s * d[..., 0]], -1).reshape(len(root), -1)
        return m.concatenate([obs, ahead, self.height_map(root, heading)], -1)

    def _task_info(self, body):
        b = self.backend
        _, error = path_reward(body.pos[:, 0, :2], self._points[:, 0])
        t = self.elapsed / 30.0 / PATH_DT
        i = b.asarray(t, "int").clip(max=PATH_VERTICES - 2)
        f = (t - i).clip(0.0, 1.0)
        rows = b.arange(self.num_envs)
        length = self.path_length[rows, i] + f * (self.path_length[rows, i + 1] - self.path_length[rows, i])
        return {"path_error": error, "path_point": b.copy(self._points[:, 0]), "path_length": length,
                "start_tile": b.copy(self.start_tile)}

    def _markers(self, world):
        # The current point (orange) and the ten ahead (green), 0.1 m above the terrain.
        pts = np.asarray(self.backend.to_numpy(self._points[world]), np.float64)
        ground = np.zeros(len(pts)) if self.terrain is None else self.terrain.height(pts)
        pos = np.concatenate([pts, ground[:, None] + 0.1], -1)
        return [(pos[:1], (1.0, 0.55, 0.1, 0.95), 0.06), (pos[1:], (0.2, 0.85, 0.3, 0.9), 0.04)]


__all__ = ["TerrainVecEnv", "height_map", "map_obs", "map_points", "path_reward", "make_paths", "path_at"]
