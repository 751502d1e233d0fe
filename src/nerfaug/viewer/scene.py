"""The 3D scene of a session (`draw`): its nodes named so a test can find them through viser's
server side (`server.scene.get_handle_by_name`):

    /training/NAME        the training cameras (blue frusta with their images)
    /held_out/NAME        the source's test views (grey frusta)
    /candidates           the candidate views, coloured by the last proposal's score (`COLOUR_MAP`)
    /proposals/P/rank_K   proposal P's views (orange; the picked proposal magenta, labelled by rank)
    /hemisphere/...       its centre, its rings and meridians at `radius`, its up axis
    /box                  the NeRF's box, the edges of [-h, h]^3 in the engine frame
"""

from __future__ import annotations

import math
from pathlib import PurePosixPath

import numpy as np
import viser
import viser.transforms as vtf

from nerfaug.data.world_frame import Hemisphere
from nerfaug.viewer.snapshot import Frustum, Snapshot, thumbnail

TRAINING, HELD_OUT = (40, 110, 230), (150, 150, 150)
PROPOSED, PICKED = (255, 150, 40), (230, 0, 140)
HEMISPHERE, BOX, UNSCORED = (120, 160, 120), (90, 90, 90), (200, 200, 200)
# viridis at five stops (matplotlib's values), interpolated: low scores dark blue, high ones yellow.
COLOUR_MAP = np.array(
    [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]],
    dtype=np.float64,
)


def colours(values: np.ndarray) -> np.ndarray:
    """uint8 (n, 3): `values` (n,) from their least (dark) to their largest (bright) on `COLOUR_MAP`.

    >>> colours(np.array([0.0, 1.0])).tolist()
    [[68, 1, 84], [253, 231, 37]]
    """
    values = np.asarray(values, dtype=np.float64)
    low, high = (float(values.min()), float(values.max())) if values.size else (0.0, 1.0)
    t = (values - low) / (high - low) if high > low else np.zeros_like(values)
    stops = np.linspace(0, 1, len(COLOUR_MAP))
    out = np.stack([np.interp(t, stops, COLOUR_MAP[:, c]) for c in range(3)], axis=-1)
    return out.round().astype(np.uint8)


def colour_bar(width: int = 256, height: int = 14) -> np.ndarray:
    """uint8 (height, width, 3): `COLOUR_MAP` from low (left) to high (right)."""
    return np.repeat(colours(np.linspace(0, 1, width))[None], height, axis=0)


def opencv_pose(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A world-frame OpenGL camera-to-world (4, 4) as viser places a frustum (OpenCV: +z forward,
    +y down): its quaternion (w, x, y, z) and position."""
    rotation = pose[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    return vtf.SO3.from_matrix(rotation).wxyz, pose[:3, 3]


def _frustum(server: viser.ViserServer, name: str, camera: Frustum, scale: float, colour, image=None):
    wxyz, position = opencv_pose(camera.pose)
    return server.scene.add_camera_frustum(
        name, fov=camera.fov_y, aspect=camera.aspect, scale=scale, color=colour, image=image,
        wxyz=wxyz, position=position, **_screen(2.0),
    )  # fmt: skip


def _screen(pixels: float) -> dict:
    """A line's thickness in screen pixels: the same on a near and a far frustum."""
    return {"thickness": pixels, "thickness_units": "screen"}


def node_name(index: int, name: str) -> str:
    """A scene node's name for view `index` named `name` (a file path): "003_r_12" (unique, no slashes).

    >>> node_name(3, "./train/r_12.png")
    '003_r_12'
    """
    stem = PurePosixPath(name.replace("\\", "/")).name.split(".")[0] or "view"
    return f"{index:03d}_{stem}"


def hemisphere_lines(hemisphere: Hemisphere, rings: int = 4, meridians: int = 12, points: int = 48) -> np.ndarray:
    """Line segments (m, 2, 3), world frame: the hemisphere's rings (elevations 0 up to the pole)
    and meridians at its radius about its centre."""
    axes = hemisphere.rotation().numpy()  # columns: the engine's x, y and up in the world
    centre, radius = np.asarray(hemisphere.centre), hemisphere.radius

    def point(elevation, azimuth):
        local = np.stack(
            [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], axis=-1
        )
        return centre + radius * local @ axes.T

    segments = []
    for elevation in np.linspace(0, math.pi / 2, rings + 1)[:-1]:
        ring = point(np.full(points + 1, elevation), np.linspace(0, 2 * math.pi, points + 1))
        segments += list(zip(ring[:-1], ring[1:]))
    for azimuth in np.linspace(0, 2 * math.pi, meridians + 1)[:-1]:
        arc = point(np.linspace(0, math.pi / 2, points // 4 + 1), np.full(points // 4 + 1, azimuth))
        segments += list(zip(arc[:-1], arc[1:]))
    return np.asarray(segments)


def box_lines(hemisphere: Hemisphere, half_size: float) -> np.ndarray:
    """Line segments (12, 2, 3), world frame: the edges of the engine frame's box [-h, h]^3."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64) * half_size
    world = np.asarray(hemisphere.centre) + hemisphere.scale * corners @ hemisphere.rotation().numpy().T
    edges = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
    return np.stack([np.stack([world[a], world[b]]) for a, b in edges])


def draw(server: viser.ViserServer, snapshot: Snapshot, picked: int | None, images: bool = True) -> None:
    """Draw `snapshot` anew (every node above replaced), proposal `picked` highlighted; `images`:
    the training frusta carry their images."""
    h = snapshot.hemisphere
    size = 0.08 * h.radius  # a frustum's depth: readable on the hemisphere, apart from its neighbours
    scene = server.scene
    for root in ("/training", "/held_out", "/candidates", "/proposals", "/hemisphere", "/box"):
        scene.remove_by_name(root)
    up = tuple(float(u) for u in h.up)
    scene.set_up_direction(up)
    for i, camera in enumerate(snapshot.training):
        picture = thumbnail(camera.image, snapshot.background) if images else None
        _frustum(server, f"/training/{node_name(i, camera.name)}", camera, size, TRAINING, picture)
    for i, camera in enumerate(snapshot.held_out):
        _frustum(server, f"/held_out/{node_name(i, camera.name)}", camera, size * 0.5, HELD_OUT)
    candidates = snapshot.candidates
    if len(candidates.positions):
        tint = colours(candidates.scores) if candidates.scores is not None else np.array(UNSCORED, dtype=np.uint8)
        scene.add_point_cloud(
            "/candidates", candidates.positions.astype(np.float32), tint, point_size=0.012 * h.radius,
            point_shape="circle",
        )  # fmt: skip
    fov = snapshot.training[0].fov_y if snapshot.training else math.radians(40)
    aspect = snapshot.training[0].aspect if snapshot.training else 1.0
    for proposal in snapshot.proposals:
        chosen = proposal.number == picked
        for rank, (name, pose) in enumerate(zip(proposal.names, proposal.poses)):
            node = f"/proposals/{proposal.number}/rank_{rank + 1}"
            camera, colour = Frustum(name, pose, fov, aspect), PICKED if chosen else PROPOSED
            _frustum(server, node, camera, size * (1.2 if chosen else 0.8), colour)
            if chosen:
                scene.add_label(f"{node}/label", f"#{rank + 1}", font_screen_scale=0.8)
    centre = np.asarray(h.centre, dtype=np.float64)
    scene.add_icosphere("/hemisphere/centre", radius=0.03 * h.radius, color=(220, 40, 40), position=centre)
    scene.add_line_segments("/hemisphere/rings", hemisphere_lines(h).astype(np.float32), HEMISPHERE, **_screen(1.0))
    axis = np.stack([centre, centre + 1.15 * h.radius * np.asarray(h.up)])[None].astype(np.float32)
    scene.add_line_segments("/hemisphere/up", axis, (220, 40, 40), **_screen(3.0))
    scene.add_label("/hemisphere/up/label", "up", position=tuple(axis[0, 1]))
    scene.add_line_segments("/box", box_lines(h, snapshot.box_half_size).astype(np.float32), BOX, **_screen(2.0))


def first_view(snapshot: Snapshot, distance: float = 2.6, elevation_degrees: float = 35.0) -> tuple:
    """Where a browser's camera starts (world frame): `distance` radii from the centre, on the side
    of the training cameras (behind them: their images face the viewer), `elevation_degrees` up;
    and the point it looks at, the centre."""
    h = snapshot.hemisphere
    centre, axes = np.asarray(h.centre, dtype=np.float64), h.rotation().numpy()
    if snapshot.training:
        mean = np.mean([c.pose[:3, 3] for c in snapshot.training], axis=0) - centre
        local = mean @ axes  # engine axes: x, y, up
        azimuth = math.atan2(local[1], local[0]) if np.hypot(local[0], local[1]) > 1e-9 else 0.0
    else:
        azimuth = 0.0
    elevation = math.radians(elevation_degrees)
    cos = math.cos(elevation)
    local = np.array([cos * math.cos(azimuth), cos * math.sin(azimuth), math.sin(elevation)])
    return centre + distance * h.radius * axes @ local, centre
