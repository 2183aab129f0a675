"""A maze with rooms, redrawn every episode inside jit (dm_control's `RandomMazeWithTargets`).

dm_control rebuilds its maze's wall geoms in Python at every episode from labmaze's text grid; a
compiled MJX model cannot change its geoms. Here the maze is data, not model:

- `sample_maze(rng, params)` draws a maze in JAX: a grid of `y_cells` x `x_cells` cells (row 0 at
  +y, as labmaze's text grid prints), each a wall or free, with border walls. Up to `max_rooms`
  rooms (rectangles of odd side in [room_min_size, room_max_size] rounded down to odd, placed at
  odd rows and columns, at least one wall cell apart) are free; every other odd (row, column)
  cell is free and a perfect maze joins them: Kruskal's algorithm over the odd cells in a random
  edge order, each room one node (union-find by relabelling, in `lax.fori_loop`). Every free cell
  is reachable from every other. Each room holds `spawns_per_room` spawn cells and
  `targets_per_room` target cells, distinct, drawn uniformly among its cells.
- The world holds the walls as mocap boxes of one cell each. A window of (2 `window` + 1)² boxes
  collides (`place_window`: the wall cells around the walker's cell, every control step, so MJX
  collides the walker with at most 9 boxes by default, not ~60), drawn in the hidden group 3;
  one visual-only box per grid cell (`place_visual`, once per episode: contype = conaffinity = 0,
  group 0) is what renders and vnl's in-graph camera (`vnl.vision.camera`, which ray-casts group
  0-2 boxes) see. Unused boxes wait at `HIDDEN_Z`, under the floor.

Where this differs from labmaze's generator (`labmaze.RandomMaze`, C++) and why:

- labmaze leaves some odd cells walled (e.g. cell (1, 1) of the first maze of
  `labmaze.RandomMaze(height=11, width=11, ..., random_seed=1)` with these parameters); here
  every odd cell is free and the corridors form a tree (one path between any two free cells
  outside rooms): a fixed-size JAX loop over the 2·n·(n-1) edges of the odd-cell grid, the
  simplest generator with every free cell connected. Room sizes, positions on odd cells, one wall
  between rooms, and the spawn and target counts per room are labmaze's (room sizes 4-5 give
  rooms of 3 and 5 cells, as its mazes show).
- labmaze places rooms with its own rejection scheme; here each of `max_rooms` rooms gets
  `room_tries` random placements and keeps the first that fits, in `ROOM_LAYOUTS` independent
  layouts of which the one with the most rooms is kept. Over 200 mazes with the defaults: 2, 3, 4
  rooms in 0.5%, 35.5%, 64% (labmaze: 3%, 28.5%, 68.5%), ~61 free cells of 121 (labmaze: ~59).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jp
import numpy as np
from dm_control import mjcf

from vnl.arenas import base as arena_base
from vnl.errors import VnlError

HIDDEN_Z = -50.0  # where unused wall boxes and collected targets wait
ROOM_LAYOUTS = 4  # room layouts drawn per maze; the one with the most rooms is kept


@dataclasses.dataclass(frozen=True)
class MazeParams:
    """The maze's shape (cells) and scale (m). Defaults are `basic_rodent_2020.rodent_maze_forage`'s
    `RandomMazeWithTargets(x_cells=11, y_cells=11, xy_scale=.5, z_height=.3, max_rooms=4,
    room_min_size=4, room_max_size=5, spawns_per_room=1, targets_per_room=3)`."""

    x_cells: int = 11
    y_cells: int = 11
    cell_size: float = 0.5  # dm_control's xy_scale
    wall_height: float = 0.3  # dm_control's z_height
    max_rooms: int = 4
    room_min_size: int = 4
    room_max_size: int = 5
    spawns_per_room: int = 1
    targets_per_room: int = 3
    room_tries: int = 20  # random placements tried per room
    # Walls within this many cells (Chebyshev) of the walker's cell collide; the task checks that
    # the walker cannot reach a wall beyond them within a control step.
    window: int = 1

    def validate(self) -> None:
        """Raises `VnlError` for a maze that cannot be drawn."""
        for key in ("x_cells", "y_cells"):
            n = getattr(self, key)
            if not (5 <= n <= 101 and n % 2 == 1):
                raise VnlError(f"maze.{key} must be odd, in [5, 101], got {n}")
        if not (0 < self.cell_size < 100 and 0 < self.wall_height < 100):
            raise VnlError("maze.cell_size and maze.wall_height must be in (0, 100) m")
        inner = min(self.x_cells, self.y_cells) - 2
        if not (3 <= self.room_min_size <= self.room_max_size <= inner):
            raise VnlError(
                f"need 3 <= maze.room_min_size <= maze.room_max_size <= {inner} (the grid's inside), got "
                f"{self.room_min_size} and {self.room_max_size}"
            )
        if not (1 <= self.max_rooms <= 100 and 1 <= self.room_tries <= 1000 and 0 <= self.window <= 10):
            raise VnlError("need maze.max_rooms in [1, 100], maze.room_tries in [1, 1000], maze.window in [0, 10]")
        smallest = _odd(self.room_min_size) ** 2
        if not (self.spawns_per_room >= 1 and self.targets_per_room >= 0):
            raise VnlError("maze.spawns_per_room must be >= 1 and maze.targets_per_room >= 0")
        if self.spawns_per_room + self.targets_per_room > smallest:
            raise VnlError(
                f"maze.spawns_per_room + maze.targets_per_room must fit the smallest room's {smallest} cells"
            )

    @property
    def n_spawns(self) -> int:
        return self.max_rooms * self.spawns_per_room

    @property
    def n_targets(self) -> int:
        return self.max_rooms * self.targets_per_room

    @property
    def n_window(self) -> int:
        return (2 * self.window + 1) ** 2

    @property
    def n_boxes(self) -> int:
        """Mocap wall boxes: the collidable window, then one visual box per cell."""
        return self.n_window + self.x_cells * self.y_cells


@dataclasses.dataclass(frozen=True)
class Maze:
    """One maze. `walls` (y_cells, x_cells) bool; `rooms` (max_rooms, 4) int32 rows of (top row,
    left column, height, width) with `room_valid` (max_rooms,); `spawns` (n_spawns, 2) and
    `targets` (n_targets, 2) int32 (row, column) cells with `spawn_valid` / `target_valid`
    (those of rooms not placed are False)."""

    walls: jax.Array
    rooms: jax.Array
    room_valid: jax.Array
    spawns: jax.Array
    spawn_valid: jax.Array
    targets: jax.Array
    target_valid: jax.Array


jax.tree_util.register_dataclass(
    Maze,
    data_fields=["walls", "rooms", "room_valid", "spawns", "spawn_valid", "targets", "target_valid"],
    meta_fields=[],
)


def _odd(n: int) -> int:
    return n if n % 2 else n - 1


def _place_rooms(rng: jax.Array, params: MazeParams) -> tuple[jax.Array, jax.Array]:
    """`ROOM_LAYOUTS` room layouts drawn by `_try_rooms`; the one with the most rooms (the first
    of those) is kept: one layout alone leaves a single room in ~5% of mazes (a 5-cell room in
    the middle blocks the rest), labmaze never does."""
    rooms, valid = jax.vmap(lambda k: _try_rooms(k, params))(jax.random.split(rng, ROOM_LAYOUTS))
    best = jp.argmax(jp.sum(valid, axis=1))
    return rooms[best], valid[best]


def _try_rooms(rng: jax.Array, params: MazeParams) -> tuple[jax.Array, jax.Array]:
    """Rooms placed by rejection: (max_rooms, 4) int32 (top, left, height, width) and (max_rooms,)
    bool. Sides are odd, corners on odd cells, rooms one wall cell apart at least."""
    p = params
    sizes = np.arange(_odd(p.room_min_size), _odd(p.room_max_size) + 1, 2)
    # A side drawn uniformly in [min, max], then rounded down to odd (labmaze's 4-5 give 3 and 5).
    side_p = np.bincount([(_odd(s) - sizes[0]) // 2 for s in range(p.room_min_size, p.room_max_size + 1)])
    side_p = jp.asarray(side_p / side_p.sum(), jp.float32)
    n = p.max_rooms * p.room_tries
    k_h, k_w, k_r, k_c = jax.random.split(rng, 4)
    h = jp.asarray(sizes)[jax.random.choice(k_h, len(sizes), (n,), p=side_p)]
    w = jp.asarray(sizes)[jax.random.choice(k_w, len(sizes), (n,), p=side_p)]
    # Odd top rows 1, 3, ... with the room inside the border: top + h <= y_cells - 1, (y_cells - h) / 2 choices.
    top = 1 + 2 * jp.floor(jax.random.uniform(k_r, (n,)) * ((p.y_cells - h) // 2)).astype(jp.int32)
    left = 1 + 2 * jp.floor(jax.random.uniform(k_c, (n,)) * ((p.x_cells - w) // 2)).astype(jp.int32)
    tries = jp.stack([top, left, h, w], axis=-1).astype(jp.int32)

    def attempt(i: jax.Array, carry: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        rooms, valid = carry
        room = i // p.room_tries
        t, lft, hh, ww = tries[i]
        # Apart: a wall row or column between them (corners on odd cells make the gap odd too).
        clash = (
            (t <= rooms[:, 0] + rooms[:, 2])
            & (rooms[:, 0] <= t + hh)
            & (lft <= rooms[:, 1] + rooms[:, 3])
            & (rooms[:, 1] <= lft + ww)
        )
        ok = ~valid[room] & ~jp.any(clash & valid)
        return rooms.at[room].set(jp.where(ok, tries[i], rooms[room])), valid.at[room].set(valid[room] | ok)

    rooms0 = jp.zeros((p.max_rooms, 4), jp.int32)
    valid0 = jp.zeros(p.max_rooms, bool)
    return jax.lax.fori_loop(0, n, attempt, (rooms0, valid0))


def _in_rooms(rooms: jax.Array, valid: jax.Array, params: MazeParams) -> jax.Array:
    """(max_rooms, y_cells, x_cells) bool: which cells each placed room covers."""
    r = jp.arange(params.y_cells)[None, :, None]
    c = jp.arange(params.x_cells)[None, None, :]
    t, lft, h, w = (rooms[:, k][:, None, None] for k in range(4))
    return valid[:, None, None] & (r >= t) & (r < t + h) & (c >= lft) & (c < lft + w)


def _carve(rng: jax.Array, covers: jax.Array, params: MazeParams) -> jax.Array:
    """The wall grid (y_cells, x_cells) bool: rooms and odd cells free, joined by Kruskal's
    spanning tree over the odd cells (rooms pre-joined), in a random edge order."""
    p = params
    ny, nx = (p.y_cells - 1) // 2, (p.x_cells - 1) // 2  # odd cells per column / row
    # Edges between horizontally, then vertically adjacent odd cells: node ids and the wall between.
    a, b = np.meshgrid(np.arange(ny), np.arange(nx - 1), indexing="ij")
    horizontal = (a * nx + b, a * nx + b + 1, 2 * a + 1, 2 * b + 2)
    a, b = np.meshgrid(np.arange(ny - 1), np.arange(nx), indexing="ij")
    vertical = (a * nx + b, (a + 1) * nx + b, 2 * a + 2, 2 * b + 1)
    edges = np.stack([np.concatenate([h.ravel(), v.ravel()]) for h, v in zip(horizontal, vertical, strict=True)], -1)
    edges = jp.asarray(edges, jp.int32)[jax.random.permutation(rng, len(edges))]
    # A node's label: its own id, or its room's first node's (all of a room is one node).
    nodes_in = covers[:, 1::2, 1::2].reshape(p.max_rooms, ny * nx)
    first = jp.argmax(nodes_in, axis=1)
    labels = jp.arange(ny * nx)
    for k in range(p.max_rooms):
        labels = jp.where(nodes_in[k], first[k], labels)
    walls = jp.ones((p.y_cells, p.x_cells), bool).at[1::2, 1::2].set(False) & ~jp.any(covers, axis=0)

    def join(i: jax.Array, carry: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        labels, walls = carry
        u, v, r, c = edges[i]
        lu, lv = labels[u], labels[v]
        apart = lu != lv
        labels = jp.where(apart & (labels == lv), lu, labels)
        return labels, walls.at[r, c].set(walls[r, c] & ~apart)

    return jax.lax.fori_loop(0, len(edges), join, (labels, walls))[1]


def _room_cells(rng: jax.Array, rooms: jax.Array, k: int, params: MazeParams) -> jax.Array:
    """`k` distinct cells drawn uniformly in each room: (max_rooms, k, 2) int32 (row, column)."""
    side = _odd(params.room_max_size)
    dr, dc = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    dr, dc = jp.asarray(dr.ravel()), jp.asarray(dc.ravel())

    def one(key: jax.Array, room: jax.Array) -> jax.Array:
        inside = (dr < room[2]) & (dc < room[3])
        score = jp.where(inside, jax.random.uniform(key, dr.shape), -1.0)
        pick = jp.argsort(-score)[:k]
        return jp.stack([room[0] + dr[pick], room[1] + dc[pick]], axis=-1).astype(jp.int32)

    return jax.vmap(one)(jax.random.split(rng, params.max_rooms), rooms)


def sample_maze(rng: jax.Array, params: MazeParams) -> Maze:
    """Draws a maze (see the module docstring); deterministic per key, jit- and vmap-able."""
    p = params
    k_rooms, k_carve, k_cells = jax.random.split(rng, 3)
    rooms, valid = _place_rooms(k_rooms, p)
    walls = _carve(k_carve, _in_rooms(rooms, valid, p), p)
    cells = _room_cells(k_cells, rooms, p.spawns_per_room + p.targets_per_room, p)
    spawns = cells[:, : p.spawns_per_room].reshape(-1, 2)
    targets = cells[:, p.spawns_per_room :].reshape(-1, 2)
    return Maze(
        walls=walls,
        rooms=rooms,
        room_valid=valid,
        spawns=spawns,
        spawn_valid=jp.repeat(valid, p.spawns_per_room),
        targets=targets,
        target_valid=jp.repeat(valid, p.targets_per_room),
    )


def cell_centre(cells: jax.Array, params: MazeParams) -> jax.Array:
    """(row, column) cells (..., 2) -> their centres' world (x, y) (..., 2), as dm_control's
    `MazeWithTargets.grid_to_world_positions`: column along +x, row 0 at the top (+y)."""
    rc = jp.asarray(cells, jp.float32)
    x = (rc[..., 1] - (params.x_cells - 1) / 2) * params.cell_size
    y = -(rc[..., 0] - (params.y_cells - 1) / 2) * params.cell_size
    return jp.stack([x, y], axis=-1)


def cell_of(xy: jax.Array, params: MazeParams) -> jax.Array:
    """World (x, y) (..., 2) -> the (row, column) of the cell holding it (..., 2) int32, clipped
    to the grid."""
    col = jp.round(xy[..., 0] / params.cell_size + (params.x_cells - 1) / 2)
    row = jp.round(-xy[..., 1] / params.cell_size + (params.y_cells - 1) / 2)
    rc = jp.stack([row, col], axis=-1).astype(jp.int32)
    return jp.clip(rc, 0, jp.asarray([params.y_cells - 1, params.x_cells - 1]))


def window_cells(maze: Maze, xy: jax.Array, params: MazeParams) -> tuple[jax.Array, jax.Array]:
    """The cells of the collision window around the walker at `xy` (2,): (n_window, 2) int32 and
    whether each is a wall in the grid (n_window,) bool."""
    w = params.window
    dr, dc = np.meshgrid(np.arange(-w, w + 1), np.arange(-w, w + 1), indexing="ij")
    cells = cell_of(xy, params)[None] + jp.asarray(np.stack([dr.ravel(), dc.ravel()], -1), jp.int32)
    inside = (cells >= 0).all(-1) & (cells[:, 0] < params.y_cells) & (cells[:, 1] < params.x_cells)
    r = jp.clip(cells[:, 0], 0, params.y_cells - 1)
    c = jp.clip(cells[:, 1], 0, params.x_cells - 1)
    return cells, inside & maze.walls[r, c]


def _boxes(cells: jax.Array, wall: jax.Array, params: MazeParams) -> jax.Array:
    xy = jp.where(wall[:, None], cell_centre(cells, params), 0.0)
    z = jp.where(wall, params.wall_height / 2, HIDDEN_Z)
    return jp.concatenate([xy, z[:, None]], axis=-1)


def place_window(maze: Maze, xy: jax.Array, params: MazeParams) -> jax.Array:
    """Mocap positions of the collidable boxes for a walker at `xy` (2,): (n_window, 3)."""
    cells, wall = window_cells(maze, xy, params)
    return _boxes(cells, wall, params)


def place_visual(maze: Maze, params: MazeParams) -> jax.Array:
    """Mocap positions of the visual boxes, one per cell in row-major order: (y_cells·x_cells, 3)."""
    r, c = np.meshgrid(np.arange(params.y_cells), np.arange(params.x_cells), indexing="ij")
    cells = jp.asarray(np.stack([r.ravel(), c.ravel()], -1), jp.int32)
    return _boxes(cells, maze.walls.reshape(-1), params)


def build(params: MazeParams) -> mjcf.RootElement:
    """The maze's MJCF: headlight, skybox, a floor plane under the grid, the window of collidable
    wall boxes (group 3), one visual box per cell, and dm_control's `top_camera` above the centre."""
    root = arena_base.new_arena("maze", "floor", (0.2, 0.3, 0.4), (0.1, 0.2, 0.3), (1, 1), texuniform=True)
    root.asset.add("material", name="wall", rgba=[0.55, 0.5, 0.45, 1.0])
    half_x, half_y = params.x_cells * params.cell_size / 2, params.y_cells * params.cell_size / 2
    # contype 0: the floor collides with the walker (contype 1) but not with the wall boxes: MJX
    # pairs mocap boxes with the world's plane (MuJoCo C skips static pairs), and boxes waiting
    # 50 m under it gave contacts 50 m deep, forces of 1e20 and a blown-up step.
    root.worldbody.add(
        "geom", name="floor", type="plane", size=[half_x, half_y, 0.1], material="floor", contype=0, conaffinity=1
    )
    half = [params.cell_size / 2, params.cell_size / 2, params.wall_height / 2]
    for i in range(params.n_boxes):
        collide = i < params.n_window
        body = root.worldbody.add("body", name=f"wall_{i}", mocap=True, pos=[0, 0, HIDDEN_Z])
        body.add(
            "geom",
            name=f"wall_{i}",
            type="box",
            size=half,
            material="wall",
            contype=0,
            conaffinity=1 if collide else 0,
            group=3 if collide else 0,  # the visual boxes are what renders and cameras show
        )
    # dm_control's top camera: straight down from above the centre, the whole maze in view.
    fovy = 45.0
    height = 1.1 * max(half_x, half_y) / np.tan(np.radians(fovy / 2))
    root.worldbody.add("camera", name="top_camera", pos=[0, 0, height], zaxis=[0, 0, 1], fovy=fovy)
    return root


def text_grid(maze: Maze) -> str:
    """The maze as labmaze prints it: '*' walls, ' ' free, 'P' spawns, 'G' targets; for tests."""
    grid = np.where(np.asarray(maze.walls), "*", " ").astype("<U1")
    for cells, valid, mark in ((maze.spawns, maze.spawn_valid, "P"), (maze.targets, maze.target_valid, "G")):
        for (r, c), ok in zip(np.asarray(cells), np.asarray(valid), strict=True):
            if ok:
                grid[r, c] = mark
    return "\n".join("".join(row) for row in grid)
