"""Procedural terrain for `SMPL/Terrain-v0`: a seeded height grid in pure NumPy (REFERENCE.md
section 8, PULSE's pedestrian terrain), and batched height lookups into it (`lookup`: NumPy arrays
or torch tensors).

The terrain is a grid of `size` = (rows, columns) square tiles of `tile_size` m (20 m), surrounded
by a flat border, sampled every `SPACING` = 0.1 m and rounded to 0.005 m. Each tile has a type and
a difficulty d in [0, 1]:

| type | surface |
|---|---|
| smooth_slope | pyramid of gradient 0.7 d, up or down (a coin per tile) |
| rough_slope | the same plus +-0.1 m noise (drawn every 0.2 m, bilinear in between) |
| stairs_up | rings of steps 0.31 m deep, 0.05 + 0.175 d high, rising to the centre |
| stairs_down | the same, descending to the centre |
| obstacles | 40 rectangles per 400 m^2, sides 1-2 m, heights +-h or +-h/2, h = 0.025 + 0.15 d |
| poles | 10 + 40 d poles per 400 m^2, 0.2 m square tops, 1.0-2.5 m tall |
| flat | level ground |

Every tile has a flat 3 x 3 m platform at its centre (legged_gym's pyramid terrains have one; the
spawn points of the task lie on it, so a start pose is never on a pole or a step edge); poles keep
2 m clear of the centre. All tiles meet the border at height 0, so neighbours join without cliffs.

Tile types are allocated exactly in proportion to their shares (largest remainders, then shuffled
by the seed), so shares hold over the whole grid up to one tile per type; difficulty is one value,
a (min, max) range drawn per tile, or "levels" (row r has difficulty r / rows, PULSE's curriculum
layout). Same arguments and seed -> the same terrain, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .features import xp

SPACING = 0.1            # m between height samples (REFERENCE section 8)
VERTICAL_STEP = 0.005    # m: heights are rounded to this
PLATFORM = 1.5           # m: half-width of each tile's flat centre
POLE_CLEARANCE = 2.0     # m: half-width of the pole-free square around a tile's centre
TERRAIN_TYPES = ("smooth_slope", "rough_slope", "stairs_up", "stairs_down", "obstacles", "poles", "flat")
# PULSE's shares (stepping stones, share 0 there, are left out).
DEFAULT_SHARES = {"smooth_slope": 0.2, "rough_slope": 0.1, "stairs_up": 0.15, "stairs_down": 0.15,
                  "obstacles": 0.05, "poles": 0.25, "flat": 0.1}
STAIR_DEPTH = 0.31


def stair_height(difficulty):
    return 0.05 + 0.175 * np.asarray(difficulty)


def obstacle_height(difficulty):
    return 0.025 + 0.15 * np.asarray(difficulty)


def slope_gradient(difficulty):
    return 0.7 * np.asarray(difficulty)


# ------------------------------------------------------------------------------------ arguments
def parse_shares(terrain) -> dict[str, float]:
    """`terrain=` as {type: share}: "mixed" (PULSE's shares), a type name, a list of names (equal
    shares) or a mapping of shares summing to 1. ValueError names the kwarg."""
    if isinstance(terrain, str):
        if terrain == "mixed":
            return dict(DEFAULT_SHARES)
        if terrain in TERRAIN_TYPES:
            return {terrain: 1.0}
        raise ValueError(f"terrain must be 'mixed', 'flat', one of {TERRAIN_TYPES}, a list of them or a "
                         f"mapping of shares, got {terrain!r}")
    if isinstance(terrain, Mapping):
        shares = {}
        for name, share in terrain.items():
            if name not in TERRAIN_TYPES:
                raise ValueError(f"terrain: unknown type {name!r}; known: {TERRAIN_TYPES}")
            try:
                share = float(share)
            except (TypeError, ValueError):
                raise ValueError(f"terrain: share of {name!r} must be a number, got {share!r}") from None
            if not np.isfinite(share) or share < 0:
                raise ValueError(f"terrain: share of {name!r} must be a non-negative number, got {share!r}")
            shares[name] = share
        total = sum(shares.values())
        if not shares or abs(total - 1.0) > 1e-6:
            raise ValueError(f"terrain: shares must sum to 1, got {total:.6g} for {dict(terrain)!r}")
        return {k: v for k, v in shares.items() if v > 0}
    try:
        names = list(terrain)
    except TypeError:
        raise ValueError(f"terrain must be a type name, a list of type names or a mapping of shares, "
                         f"got {terrain!r}") from None
    unknown = [n for n in names if n not in TERRAIN_TYPES]
    if not names or unknown:
        raise ValueError(f"terrain: unknown or missing types {unknown or names!r}; known: {TERRAIN_TYPES}")
    return {n: 1.0 / len(set(names)) for n in dict.fromkeys(names)}


def check_size(size) -> tuple[int, int]:
    try:
        rows, cols = (int(v) for v in size)
        exact = all(float(v) == int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"terrain_size must be (rows, columns) of tiles, got {size!r}") from None
    if not exact or rows < 1 or cols < 1:
        raise ValueError(f"terrain_size must be (rows, columns) with whole numbers >= 1, got {size!r}")
    return rows, cols


def tile_difficulty(difficulty, rows: int, cols: int, rng: np.random.Generator) -> np.ndarray:
    """(rows, cols) difficulties in [0, 1] from `terrain_difficulty` (module docstring)."""
    if isinstance(difficulty, str):
        if difficulty != "levels":
            raise ValueError(f"terrain_difficulty must be a number in [0, 1], a (min, max) range or 'levels', "
                             f"got {difficulty!r}")
        return np.repeat((np.arange(rows) / rows)[:, None], cols, 1)
    if np.ndim(difficulty) == 0:
        try:
            d = float(difficulty)
        except (TypeError, ValueError):
            raise ValueError(f"terrain_difficulty must be a number in [0, 1], got {difficulty!r}") from None
        if not 0.0 <= d <= 1.0:
            raise ValueError(f"terrain_difficulty must lie in [0, 1], got {difficulty!r}")
        return np.full((rows, cols), d)
    try:
        lo, hi = (float(v) for v in difficulty)
    except (TypeError, ValueError):
        raise ValueError(f"terrain_difficulty must be a number, a (min, max) pair or 'levels', got {difficulty!r}") from None
    if not (0.0 <= lo <= hi <= 1.0):
        raise ValueError(f"terrain_difficulty range must satisfy 0 <= min <= max <= 1, got {difficulty!r}")
    return rng.uniform(lo, hi, (rows, cols))


def allocate(shares: dict[str, float], count: int, rng: np.random.Generator) -> np.ndarray:
    """`count` type indices (into TERRAIN_TYPES) in proportion to `shares`, shuffled."""
    names = list(shares)
    exact = np.array([shares[n] for n in names]) * count
    k = np.floor(exact).astype(int)
    k[np.argsort(-(exact - k), kind="stable")[: count - k.sum()]] += 1  # largest remainders
    kinds = np.repeat([TERRAIN_TYPES.index(n) for n in names], k)
    return rng.permutation(kinds)


# ------------------------------------------------------------------------------------ the terrain
@dataclass
class Terrain:
    """A height grid: `heights[i, j]` (m) at x = x0 + j SPACING, y = y0 + i SPACING (world).

    types / difficulty: (rows, cols) per tile (index into TERRAIN_TYPES; tile (r, c) spans
    x in x0 + border + c tile_size ..., y likewise with r); centres: (rows * cols, 2) world xy of
    the tile centres, row-major.
    """

    heights: np.ndarray
    x0: float
    y0: float
    tile_size: float
    border: float
    types: np.ndarray
    difficulty: np.ndarray

    def __post_init__(self):
        self.shape = self.heights.shape
        # The maximum over +-0.3 m around each sample: what a body within that distance of a
        # point may meet (start poses are lifted above it).
        self.dilated = max_filter(self.heights, 3)
        rows, cols = self.types.shape
        r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
        self.centres = np.stack([self.x0 + self.border + (c.ravel() + 0.5) * self.tile_size,
                                 self.y0 + self.border + (r.ravel() + 0.5) * self.tile_size], -1)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the grid (m)."""
        ny, nx = self.shape
        return self.x0, self.x0 + (nx - 1) * SPACING, self.y0, self.y0 + (ny - 1) * SPACING

    def height(self, xy, mode: str = "bilinear") -> np.ndarray:
        """Terrain heights (...) at world points xy (..., 2), batched: bilinear between the four
        surrounding samples, their "min" / "max", or "dilated" (the highest sample within 0.3 m);
        points off the grid read its edge."""
        if mode == "dilated":  # the highest terrain within 0.3 m of the point
            return lookup(self.dilated, xy, self.x0, self.y0, "max")
        return lookup(self.heights, xy, self.x0, self.y0, mode)


def lookup(grid, xy, x0: float, y0: float, mode: str = "bilinear"):
    """Batched reads of `grid` (ny, nx), sampled every SPACING from (x0, y0), at points xy (..., 2):
    four gathers from the flat array, no loop over points. NumPy arrays, or torch tensors (grid
    and points on one device: the terrain task's warp backend)."""
    ny, nx = grid.shape
    u = ((xy[..., 0] - x0) * (1.0 / SPACING)).clip(0.0, nx - 1.000001)
    v = ((xy[..., 1] - y0) * (1.0 / SPACING)).clip(0.0, ny - 1.000001)
    # Cells clamped inside the grid: in float32 the bound above rounds up to the last sample.
    j, i = cell_index(u).clip(max=nx - 2), cell_index(v).clip(max=ny - 2)
    flat = grid.reshape(-1)
    k = i * nx + j
    h00, h01, h10, h11 = flat[k], flat[k + 1], flat[k + nx], flat[k + nx + 1]
    if mode == "bilinear":
        fu, fv = u - j, v - i
        return (h00 + fu * (h01 - h00)) + fv * ((h10 + fu * (h11 - h10)) - (h00 + fu * (h01 - h00)))
    m = xp(h00)
    if mode == "min":
        return m.minimum(m.minimum(h00, h01), m.minimum(h10, h11))
    if mode == "max":
        return m.maximum(m.maximum(h00, h01), m.maximum(h10, h11))
    raise ValueError(f"mode must be 'bilinear', 'min' or 'max', got {mode!r}")


def cell_index(x):
    """Integer parts (int64) of non-negative floats (cell indices), NumPy or torch."""
    m = xp(x)
    return x.astype(np.int64) if m is np else x.to(m.int64)


def max_filter(grid: np.ndarray, radius: int) -> np.ndarray:
    """Maximum over the (2 radius + 1)^2 square around every sample (separable, edge-padded)."""
    from numpy.lib.stride_tricks import sliding_window_view

    w = 2 * radius + 1
    out = sliding_window_view(np.pad(grid, ((0, 0), (radius, radius)), mode="edge"), w, axis=1).max(-1)
    return sliding_window_view(np.pad(out, ((radius, radius), (0, 0)), mode="edge"), w, axis=0).max(-1)


def _tile(kind: str, d: float, n: int, tile_size: float, rng: np.random.Generator) -> np.ndarray:
    """(n, n) heights of one tile, centred coordinates u (x), v (y) in [-L, L]."""
    half = tile_size / 2
    u = np.arange(n) * SPACING - half  # sample k of the tile; the centre is sample n / 2
    x, y = np.meshgrid(u, u)  # rows: y, columns: x
    ring = np.maximum(np.abs(x), np.abs(y))  # Chebyshev distance: pyramids with square rings
    inside = np.maximum(ring, PLATFORM)     # the platform is level
    if kind in ("smooth_slope", "rough_slope"):
        sign = 1.0 if rng.random() < 0.5 else -1.0
        h = sign * slope_gradient(d) * (half - inside)
        if kind == "rough_slope":
            coarse = rng.uniform(-0.1, 0.1, (int(np.ceil(tile_size / 0.2)) + 2,) * 2)
            pts = np.stack([x + half, y + half], -1)
            h = h + np.where(ring > PLATFORM, _resample(coarse, pts, 0.2), 0.0)
        return h
    if kind in ("stairs_up", "stairs_down"):
        steps = np.floor((half - inside) / STAIR_DEPTH)
        return (1.0 if kind == "stairs_up" else -1.0) * stair_height(d) * steps
    h = np.zeros((n, n))
    area = tile_size * tile_size / 400.0
    if kind == "obstacles":
        k = max(1, int(round(40 * area)))
        hmax = float(obstacle_height(d))
        sides = rng.uniform(1.0, 2.0, (k, 2))
        centre = rng.uniform(-half, half, (k, 2))
        heights = rng.choice([-hmax, -hmax / 2, hmax / 2, hmax], k)
        cover = ((np.abs(x[None] - centre[:, 0, None, None]) <= sides[:, 0, None, None] / 2)
                 & (np.abs(y[None] - centre[:, 1, None, None]) <= sides[:, 1, None, None] / 2))
        last = (cover * np.arange(1, k + 1)[:, None, None]).max(0)  # later rectangles cover earlier
        h = np.where(last > 0, heights[np.maximum(last - 1, 0)], 0.0)
        return np.where(ring > PLATFORM, h, 0.0)
    if kind == "poles":
        k = max(1, int(round((10 + 40 * d) * area)))
        # Pole centres on the grid, outside the pole-free square around the centre.
        cells = rng.integers(1, n - 2, (4 * k, 2))
        cu, cv = u[cells[:, 0]], u[cells[:, 1]]
        keep = np.maximum(np.abs(cu), np.abs(cv)) > POLE_CLEARANCE + 0.2
        cells = cells[keep][:k]
        tall = rng.uniform(1.0, 2.5, len(cells))
        for di in (-1, 0, 1):  # a 3 x 3 block of samples: 0.2 m flat top
            for dj in (-1, 0, 1):
                h[cells[:, 1] + di, cells[:, 0] + dj] = tall
        return h
    if kind == "flat":
        return h
    raise ValueError(f"unknown terrain type {kind!r}")


def _resample(coarse: np.ndarray, pts: np.ndarray, spacing: float) -> np.ndarray:
    """Bilinear reads of a grid sampled every `spacing` from (0, 0) at points (..., 2)."""
    return lookup(coarse, pts * (SPACING / spacing), 0.0, 0.0)


def _grid_length(name: str, value, minimum: float) -> float:
    """`value` as metres that are a whole number of grid steps, or a ValueError naming the kwarg.
    Finiteness comes first: NaN or inf would otherwise fail inside int() naming nothing."""
    try:
        metres = float(value)
    except (TypeError, ValueError):
        metres = np.nan
    if not (np.isfinite(metres) and metres >= minimum
            and abs(round(metres / SPACING) * SPACING - metres) < 1e-9):
        raise ValueError(f"{name} must be a finite multiple of {SPACING} m, at least {minimum} m, got {value!r}")
    return metres


def make_terrain(terrain="mixed", difficulty="levels", size=(4, 4), tile_size: float = 20.0,
                 border: float = 10.0, seed: int = 0) -> Terrain:
    """The terrain of the module docstring, centred on the world origin. Same arguments -> same
    heights. ValueError names a bad kwarg (as the env spells it)."""
    shares = parse_shares(terrain)
    rows, cols = check_size(size)
    tile_size = _grid_length("tile_size", tile_size, 2 * POLE_CLEARANCE + 1.0)
    border = _grid_length("terrain_border", border, 0.0)
    n, b = int(round(tile_size / SPACING)), int(round(border / SPACING))
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"terrain_seed must be an integer >= 0, got {seed!r}")
    rng = np.random.default_rng(int(seed))
    diff = tile_difficulty(difficulty, rows, cols, rng)
    types = allocate(shares, rows * cols, rng).reshape(rows, cols)
    heights = np.zeros((rows * n + 2 * b + 1, cols * n + 2 * b + 1))
    for r in range(rows):  # a loop over tiles, once, at construction
        for c in range(cols):
            heights[b + r * n:b + (r + 1) * n, b + c * n:b + (c + 1) * n] = _tile(
                TERRAIN_TYPES[types[r, c]], float(diff[r, c]), n, tile_size, rng)
    heights = np.round(heights / VERTICAL_STEP) * VERTICAL_STEP
    extent_x, extent_y = (heights.shape[1] - 1) * SPACING, (heights.shape[0] - 1) * SPACING
    return Terrain(heights, -extent_x / 2, -extent_y / 2, tile_size, border, types, diff)
