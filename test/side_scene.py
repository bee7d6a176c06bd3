"""One part on a grey table seen by the default rig's side camera, for the pose checks' tests
that read the colour image (flat parts, near-symmetric turns)."""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.common import MeshRenderer, default_rig

SIDE = default_rig()['side']
# a table 2 x 2 m in the world's z = 0 plane: (vertices m, faces)
TABLE = (np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float64),
         np.array([[0, 1, 2], [0, 2, 3]]))
PART_RGB = np.array([70.0, 100.0, 190.0])


def side_scene(vertices: np.ndarray, faces: np.ndarray, T_world_object: np.ndarray, *,
               noise_m: float, seed: int = 0, shaded: bool = False
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Side view of the part (vertices m) on the table: (rgb (h, w, 3) uint8, depth (h, w)
    float32 m with Gaussian noise of ``noise_m``, part mask (h, w) bool). ``shaded``: the
    part lit from the camera (a surface seen at a grazing angle, a hole's wall, is darker);
    else one flat colour."""
    renderer = MeshRenderer()
    renderer.add_mesh(*TABLE)
    renderer.add_mesh(vertices, faces, T_world_object)
    view = renderer.render(SIDE.intrinsics, SIDE.T_world_camera)
    rng = np.random.default_rng(seed)
    part = view.instance == 1
    rgb = np.clip(rng.normal(120.0, 4.0, part.shape + (3,)), 0, 255)
    if shaded:
        light = np.abs(np.sum(view.normals_c * view.ray_dirs_c, axis=-1))
        rgb[part] = PART_RGB * (0.2 + 0.8 * light[part, None])
    else:
        rgb[part] = PART_RGB
    depth = view.depth_m + rng.normal(0.0, noise_m, part.shape).astype(np.float32)
    return rgb.astype(np.uint8), np.where(view.depth_m > 0, depth, 0).astype(np.float32), part


def holed_plate() -> tuple[np.ndarray, np.ndarray]:
    """A plate 60 x 40 x 4 mm with an 8 mm square hole off the middle (boxes): (vertices m,
    faces)."""
    import pytest

    from tlessbot_ros.core.common import make_transform

    trimesh = pytest.importorskip('trimesh')
    boxes = [((0, 0, 0), (0.012, 0.04, 0.004)), ((0.020, 0, 0), (0.06, 0.04, 0.004)),
             ((0.012, 0, 0), (0.020, 0.010, 0.004)), ((0.012, 0.018, 0), (0.020, 0.04, 0.004))]
    meshes = [trimesh.creation.box(extents=np.subtract(hi, lo), transform=make_transform(
        np.eye(3), np.add(lo, hi) / 2)) for lo, hi in boxes]
    mesh = trimesh.util.concatenate(meshes)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def drilled_block():
    """The generator's drilled block (40 x 30 x 20 mm, two vertical holes, a cross hole,
    chamfered vertical edges): (vertices m, faces, the object with its templates on its base,
    seen by the side camera)."""
    from tlessbot_ros.core.common import make_transform
    from tlessbot_ros.core.pose import build_database
    from tlessbot_ros.tools.support import part_generator as gen

    sdf, (low, high) = gen.part_shapes()['block_drilled']
    v, f = gen.mesh_part(sdf, low, high, spacing_mm=0.7)
    v = v / 1000.0
    lift = make_transform(np.eye(3), [0.0, 0.0, -float(v[:, 2].min())])
    db = build_database([(1, v, f, [(lift, 1.0)], None)], intrinsics=SIDE.intrinsics,
                        T_world_camera=SIDE.T_world_camera)
    return v, f, db[1]


def block_on_a_side(vertices: np.ndarray, yaw_deg: float) -> np.ndarray:
    """(4, 4) T_world_object of a part (vertices m) turned a quarter about its x axis (a
    drilled block on a side, its holes level), facing the side camera turned ``yaw_deg``,
    resting on the table a little off the middle."""
    from tlessbot_ros.core.common import make_transform, rotation_about_axis

    look = SIDE.T_world_camera[:3, 2]
    facing = np.degrees(np.arctan2(look[1], look[0])) + 90.0
    R = rotation_about_axis(np.array([0, 0, 1.0]), np.radians(facing + yaw_deg)) @ \
        rotation_about_axis(np.array([1.0, 0, 0]), np.pi / 2)
    return make_transform(R, [0.01, -0.01, -float((vertices @ R.T)[:, 2].min())])


def turn_axis(S: np.ndarray) -> np.ndarray:
    """The axis (3,) of the turn ``S`` (4, 4)."""
    w, V = np.linalg.eig(S[:3, :3])
    return np.real(V[:, np.argmin(np.abs(w - 1))])


def block_with_box_turns():
    """The generator's drilled block: (vertices m, faces), the object (templates on its
    base), its box turns (:func:`~tlessbot_ros.core.pose.half_turns.box_turns`)."""
    from tlessbot_ros.core.pose import TurnParams
    from tlessbot_ros.core.pose.half_turns import box_turns, self_half_turns

    v, f, obj = drilled_block()
    turns = self_half_turns(obj)
    return v, f, obj, turns[box_turns(obj, turns, TurnParams())]


def side_evidence(rgb: np.ndarray, depth: np.ndarray, mask: np.ndarray, T_world_object):
    """(T_camera_object, [the side view's evidence], its ROI points) of a part rendered by
    :func:`side_scene` at ``T_world_object``, with ``depth`` (m, 0 = none) as measured."""
    from tlessbot_ros.core.common import depth_to_points, plane_of_frame
    from tlessbot_ros.core.pose.flat import ViewEvidence

    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=mask & (depth > 0))
    view = ViewEvidence(rgb, mask, SIDE.intrinsics, np.eye(4), depth,
                        plane_of_frame(SIDE.T_world_camera), np.zeros_like(mask))
    return np.linalg.inv(SIDE.T_world_camera) @ T_world_object, [view], points


RADIUS, THICK = 0.0235, 0.0044           # disc_8f of the held-out family 8: 47 x 4.4 mm
HOLE_R, HOLE_AT = 0.0019, 0.016          # four 3.8 mm holes 16 mm from the axis


def holed_disc_mesh(holes: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A closed mesh of a disc (vertices m, faces) with a 2 mm bore and ``holes`` round
    through-holes on a circle: cells of a polar grid (0.5 mm by 2 degrees) with a top, a
    bottom and a wall where a neighbour is missing, those whose centre lies in a hole left
    out."""
    radii = np.linspace(0.001, RADIUS, 46)
    angles = np.radians(np.arange(0.0, 360.0, 2.0))
    centres = [HOLE_AT * np.array([np.cos(a), np.sin(a)])
               for a in 2 * np.pi * np.arange(holes) / max(holes, 1)]

    def kept(i: int, j: int) -> bool:
        if i < 0 or i >= len(radii) - 1:
            return False
        r = (radii[i] + radii[i + 1]) / 2
        a = angles[j % len(angles)] + np.radians(1.0)
        p = r * np.array([np.cos(a), np.sin(a)])
        return all(np.linalg.norm(p - c) > HOLE_R for c in centres)

    vertices: list[np.ndarray] = []
    faces: list[list[int]] = []

    def quad(corners: list[np.ndarray]) -> None:
        n = len(vertices)
        vertices.extend(corners)
        faces.extend([[n, n + 1, n + 2], [n, n + 2, n + 3]])

    def point(i: int, j: int, z: float) -> np.ndarray:
        a = angles[j % len(angles)]
        return np.array([radii[i] * np.cos(a), radii[i] * np.sin(a), z])

    for i in range(len(radii) - 1):
        for j in range(len(angles)):
            if not kept(i, j):
                continue
            top = [point(i, j, THICK), point(i + 1, j, THICK), point(i + 1, j + 1, THICK),
                   point(i, j + 1, THICK)]
            quad(top)
            quad([p - [0, 0, THICK] for p in top[::-1]])
            walls = {(0, 1): (i, j - 1), (1, 2): (i + 1, j), (2, 3): (i, j + 1),
                     (3, 0): (i - 1, j)}   # each edge of the top and the cell beyond it
            for (a, b), (ni, nj) in walls.items():
                if kept(ni, nj):
                    continue
                pa, pb = top[a], top[b]
                quad([pa, pa - [0, 0, THICK], pb - [0, 0, THICK], pb])
    return np.asarray(vertices), np.asarray(faces, np.int64)


def holed_disc_database(vertices: np.ndarray, faces: np.ndarray):
    """The templates of the holed disc (``holed_disc_mesh``) lying on either face, its four
    holes listed as a quarter-turn period, and its true ``T_world_object`` in the side scene
    (turned 23 degrees, 4 and -6 mm off the table's origin)."""
    from tlessbot_ros.core.common import make_transform, rotation_about_axis
    from tlessbot_ros.core.common.symmetry import Symmetries
    from tlessbot_ros.core.pose import build_database

    quarter = tuple(make_transform(rotation_about_axis([0, 0, 1], k * np.pi / 2), [0, 0, 0])
                    for k in range(4))
    flipped = make_transform(rotation_about_axis([1.0, 0.0, 0.0], np.pi), [0, 0, THICK])
    db = build_database([(1, vertices, faces, [(np.eye(4), 0.5), (flipped, 0.5)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera,
                        symmetries={1: Symmetries(discrete=quarter)})
    T_world = make_transform(rotation_about_axis([0, 0, 1], np.radians(23.0)),
                             [0.004, -0.006, 0.0])
    return db, T_world


def yaw_error_deg(T_a: np.ndarray, T_b: np.ndarray, period_deg: float) -> float:
    """|yaw of T_a against T_b| about the camera's table normal, modulo the period."""
    R = (SIDE.T_world_camera[:3, :3] @ T_a[:3, :3]) @ (SIDE.T_world_camera[:3, :3]
                                                       @ T_b[:3, :3]).T
    yaw = np.degrees(np.arctan2(R[1, 0], R[0, 0]))
    return float(abs((yaw + period_deg / 2) % period_deg - period_deg / 2))
