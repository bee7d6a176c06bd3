"""Two-view RGB-D table scenes of CAD parts, with BOP-style ground truth.

``Simulator(models, rig=None, params=SimParams(), seed=0).frame(i)`` is a pure function of
``(models, rig, params, seed, i)``: the same arguments give the same bytes. Each frame places
1-8 parts (:mod:`~tlessbot_ros.sim.scene`), picks a table (plain or textured) and a lamp
(:mod:`~tlessbot_ros.sim.materials`), ray-casts depth and instances per camera
(one Open3D ``RaycastingScene`` per frame shared by camera rays, shadow rays and the
``px_count_all`` counts, same conventions as :mod:`tlessbot_ros.core.common.render`; the
table is the analytic plane z = 0), shades
colour with cast shadows (:mod:`~tlessbot_ros.sim.shading`) and adds D415-like depth noise and
colour sensor noise (:mod:`~tlessbot_ros.sim.noise`).

Ground truth follows the BOP definitions: ``visib_fract = px_count_visib / px_count_all`` where
``px_count_all`` counts the pixels of the object rendered alone (inside the image).
"""
from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass, field, replace

import numpy as np

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    CameraMount,
    Rig,
    default_rig,
    invert_transform,
    project_points,
    transform_points,
)
from tlessbot_ros.io.models import ObjectModel
from tlessbot_ros.sim import shading
from tlessbot_ros.sim.board import SimBoard
from tlessbot_ros.sim.materials import (
    MATERIALS,
    TABLE_KINDS,
    Light,
    Table,
    make_table,
    random_light,
)
from tlessbot_ros.sim.noise import DepthNoiseParams, add_colour_noise, add_depth_noise
from tlessbot_ros.sim.raycast import PlacedParts, cast_view, lit_by_lamp, parts_roi
from tlessbot_ros.sim.scene import PlacedObject, SceneParams, hull_info, sample_scene

__all__ = ['GroundTruthObject', 'PlacedObject', 'SimParams', 'SimulatedFrame', 'SimulatedView',
           'Simulator']

NO_BOX = (-1, -1, -1, -1)


@dataclass
class GroundTruthObject:
    """Ground truth of one placed part in one view (BOP scene_gt + scene_gt_info fields).

    Attributes:
        obj_id: object class.
        T_camera_object: (4, 4) pose in the camera's optical frame, metres.
        bbox_visib: (x, y, w, h) box of the visible pixels, (-1, -1, -1, -1) if none.
        visib_fract: visible pixels / pixels of the object rendered alone.
        mask_visib: (H, W) bool visible pixels.
        px_count_all: pixels of the object rendered alone (inside the image).
        px_count_visib: visible pixels.
        bbox_obj: (x, y, w, h) box of the object rendered alone.
    """

    obj_id: int
    T_camera_object: np.ndarray
    bbox_visib: tuple[int, int, int, int]
    visib_fract: float
    mask_visib: np.ndarray
    px_count_all: int
    px_count_visib: int
    bbox_obj: tuple[int, int, int, int] = NO_BOX


@dataclass
class SimulatedView:
    """One camera's images of a frame.

    Attributes:
        name: camera name ('top', 'side').
        intrinsics: colour intrinsics (depth is aligned to colour).
        T_world_camera: (4, 4) optical frame -> world.
        rgb: (H, W, 3) uint8 RGB.
        depth_mm: (H, W) uint16 noisy depth in millimetres, 0 = invalid.
        depth_clean_m: (H, W) float32 noiseless depth in metres (table included), 0 = nothing.
        instance: (H, W) int32, -1 = background, else the index into ``frame.objects``.
        gt: per object of ``frame.objects`` (same order).
    """

    name: str
    intrinsics: CameraIntrinsics
    T_world_camera: np.ndarray
    rgb: np.ndarray
    depth_mm: np.ndarray
    depth_clean_m: np.ndarray
    instance: np.ndarray
    gt: list[GroundTruthObject] = field(default_factory=list)


@dataclass
class SimulatedFrame:
    """A scene seen by all cameras: ``views`` keyed by camera name ('top', 'side')."""

    scene_id: int
    im_id: int
    objects: list[PlacedObject]
    views: dict[str, SimulatedView]


@dataclass(frozen=True)
class SimParams:
    """Simulator options.

    ``noise_scale`` multiplies ``noise.scale`` (depth sigma and dropout; 0 = clean depth);
    ``materials`` and ``tables`` are the names drawn from (``MATERIALS``, ``TABLE_KINDS``).
    A BOP scene folder holds ``frames_per_scene`` consecutive frames (each its own arrangement).
    ``board`` lays a printed ChArUco board on the table (:mod:`~tlessbot_ros.sim.board`), None
    for none; it changes only the table's colour where it lies, and draws no random numbers, so
    everything else stays as without it.
    ``lean_prob``: the chance that a part leans, tilted out of its stable pose
    (:mod:`~tlessbot_ros.sim.scene`); 0 leaves the scenes as they were.
    """

    parts_min: int = 1
    parts_max: int = 8
    materials: tuple[str, ...] = tuple(MATERIALS)
    tables: tuple[str, ...] = TABLE_KINDS
    noise: DepthNoiseParams = DepthNoiseParams()
    noise_scale: float = 1.0
    colour_noise_sigma: float = 1.5
    blur_sigma_px: float = 0.6
    shadows: bool = True
    area_radius_m: float = 0.2
    cluster_prob: float = 0.5
    unique_classes: bool = True
    margin_px: int = 8
    frames_per_scene: int = 1000
    board: SimBoard | None = None
    lean_prob: float = 0.0

    def __post_init__(self) -> None:
        unknown = [m for m in self.materials if m not in MATERIALS]
        if unknown or not self.materials:
            raise ValueError(f'unknown materials {unknown}; choose from {sorted(MATERIALS)}')
        unknown = [t for t in self.tables if t not in TABLE_KINDS]
        if unknown or not self.tables:
            raise ValueError(f'unknown tables {unknown}; choose from {TABLE_KINDS}')
        if not 0 <= self.parts_min <= self.parts_max:
            raise ValueError(f'need 0 <= parts_min <= parts_max, got {self.parts_min}, '
                             f'{self.parts_max}')
        if self.noise_scale < 0:
            raise ValueError(f'noise_scale must be >= 0, got {self.noise_scale}')
        if not 0.0 <= self.lean_prob <= 1.0:
            raise ValueError(f'lean_prob must be in [0, 1], got {self.lean_prob}')

    @property
    def scene_params(self) -> SceneParams:
        return SceneParams(parts_min=self.parts_min, parts_max=self.parts_max,
                           area_radius_m=self.area_radius_m, cluster_prob=self.cluster_prob,
                           unique_classes=self.unique_classes, margin_px=self.margin_px,
                           lean_prob=self.lean_prob)

    @property
    def depth_noise(self) -> DepthNoiseParams:
        return replace(self.noise, scale=self.noise.scale * self.noise_scale)


@dataclass
class _Environment:
    table: Table
    light: Light
    exposure: float


def _box(mask_rows: np.ndarray, mask_cols: np.ndarray) -> tuple[int, int, int, int]:
    if len(mask_rows) == 0:
        return NO_BOX
    x0, x1 = int(mask_cols.min()), int(mask_cols.max())
    y0, y1 = int(mask_rows.min()), int(mask_rows.max())
    return (x0, y0, x1 - x0 + 1, y1 - y0 + 1)


class Simulator:
    """Deterministic two-view scene generator (see the module docstring).

    ``timings`` accumulates seconds per stage ('scene', 'raycast', 'shading', 'noise', 'gt')
    over all calls, for benchmarks.
    """

    def __init__(self, models: dict[int, ObjectModel], *, rig: Rig | None = None,
                 params: SimParams = SimParams(), seed: int = 0) -> None:
        if not models:
            raise ValueError('Simulator needs at least one model')
        self.models = dict(models)
        self.rig = rig if rig is not None else default_rig()
        self.params = params
        self.seed = int(seed)
        self.timings: dict[str, float] = defaultdict(float)
        self._camera_cache: dict[str, tuple] = {}
        self._decals: dict[str, object] = {}

    def prepare(self, *, progress: bool = False) -> None:
        """Compute the per-model caches (resting poses, collision hulls) now instead of on first
        use; frames are identical either way."""
        from tlessbot_ros.io.models import stable_poses

        items = list(self.models.values())
        if progress:
            from tqdm import tqdm

            items = tqdm(items, desc='resting poses', unit='model')
        for model in items:
            stable_poses(model)
            hull_info(model, self.params.scene_params.hull_samples)

    # -- randomness: one independent stream per (seed, index, purpose) ------------------------
    def _rng(self, index: int, *purpose: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, int(index), *purpose])

    def _environment(self, index: int) -> _Environment:
        rng = self._rng(index, 1)
        kind = self.params.tables[int(rng.integers(len(self.params.tables)))]
        table = make_table(kind, rng)
        light = random_light(rng)
        mean_albedo = float(table.texture.mean())
        exposure = rng.uniform(0.8, 1.05) * 0.55 / (mean_albedo * (light.intensity
                                                                    + light.ambient))
        exposure = float(np.clip(exposure, 0.5, 2.0))
        return _Environment(table, light, exposure)

    def _ids(self, index: int) -> tuple[int, int]:
        per = max(1, self.params.frames_per_scene)
        return index // per, index % per

    # -- public API -----------------------------------------------------------------------------
    def frame(self, index: int) -> SimulatedFrame:
        """The scene ``index``: parts, and per camera colour, depth, instances and ground truth."""
        t0 = time.perf_counter()
        objects = sample_scene(self.models, self.rig, self._rng(index, 0),
                               self.params.scene_params, materials=tuple(self.params.materials))
        return self.frame_of(index, objects, t0=t0)

    def frame_of(self, index: int, objects: list[PlacedObject], *,
                 environment: int | None = None, t0: float | None = None) -> SimulatedFrame:
        """Frame ``index`` (its noise) with the given parts placed, on the table and under the
        light of frame ``environment`` (default ``index``): e.g. one part on a turntable
        (:mod:`tlessbot_ros.sim.capture`)."""
        t0 = time.perf_counter() if t0 is None else t0
        env = self._environment(index if environment is None else environment)
        part_rng = self._rng(index, 4)
        albedo_scale = part_rng.uniform(0.9, 1.1, len(objects))
        meshes_w = []
        for obj in objects:
            model = self.models[obj.obj_id]
            # Convex-hull vertices suffice: extremes of any projection are hull vertices.
            hull = hull_info(model, self.params.scene_params.hull_samples).vertices
            meshes_w.append((transform_points(obj.T_world_object, hull), None))
        # Camera rays, shadow rays and the objects-alone counts all go through the parts' cached
        # per-model scenes.
        scene = PlacedParts(self.models, objects) if objects else None
        self.timings['scene'] += time.perf_counter() - t0
        views = {}
        for k, (name, cam) in enumerate(self.rig.cameras.items()):
            views[name] = self._render_view(index, k, cam, objects, env, scene, meshes_w,
                                            albedo_scale)
        scene_id, im_id = self._ids(index)
        return SimulatedFrame(scene_id, im_id, objects, views)

    def empty_table(self, index: int) -> dict[str, SimulatedView]:
        """Background images per camera: the table and light of ``frame(index)``, no parts."""
        env = self._environment(index)
        views = {}
        for k, (name, cam) in enumerate(self.rig.cameras.items()):
            views[name] = self._render_view(index, k, cam, [], env, None, [], np.ones(0),
                                            purpose=3)
        return views

    # -- rendering ------------------------------------------------------------------------------
    def _camera_constants(self, cam: CameraMount) -> tuple:
        """Per camera: table geometry, 1 / |ray| and the table's incidence cosine."""
        cached = self._camera_cache.get(cam.name)
        if cached is None:
            rays_c = shading.camera_rays(cam.intrinsics)
            inv_len = 1.0 / np.linalg.norm(rays_c, axis=-1)
            R = np.asarray(cam.T_world_camera[:3, :3], np.float32)
            cos_table = np.abs(rays_c @ R[2]) * inv_len  # world z seen from the camera
            cached = (shading.table_geometry(cam.intrinsics, cam.T_world_camera), inv_len,
                      cos_table)
            self._camera_cache[cam.name] = cached
        return cached

    def _board_decal(self, cam: CameraMount):
        """The board as this camera sees it (smoothed to its pixel footprint), cached."""
        board = self.params.board
        decal = self._decals.get(cam.name)
        if decal is None:
            footprint = board.footprint_m(cam.T_world_camera, cam.intrinsics.fx)
            decal = self._decals[cam.name] = board.decal(board.blur_px * footprint)
        return decal

    def _render_view(self, index: int, view_index: int, cam: CameraMount,
                     objects: list[PlacedObject], env: _Environment, scene, meshes_w: list,
                     albedo_scale: np.ndarray, purpose: int = 2) -> SimulatedView:
        p = self.params
        if p.board is not None:
            env = replace(env, table=replace(env.table, decal=self._board_decal(cam)))
        intr = cam.intrinsics
        T = np.asarray(cam.T_world_camera, dtype=np.float64)
        R = T[:3, :3].astype(np.float32)
        eye = T[:3, 3].astype(np.float32)
        h, w = intr.height, intr.width
        t0 = time.perf_counter()
        rays_c = shading.camera_rays(intr)
        if scene is not None:
            part_depth, instance, normals_w = cast_view(scene, rays_c, T,
                                                         parts_roi(meshes_w, cam))
            part = instance >= 0
        else:
            part_depth, normals_w = None, None
            instance = np.full((h, w), -1, np.int32)
            part = np.zeros((h, w), bool)
        t1 = time.perf_counter()
        self.timings['raycast'] += t1 - t0

        # Table: shaded everywhere (it is also what shows through translucent parts).
        geometry, inv_len, cos_table = self._camera_constants(cam)
        radiance, table_d, table_xy = shading.shade_table_image(env.table, intr, T, env.light,
                                                                geometry=geometry)
        depth = table_d.copy() if part_depth is None else np.where(part, part_depth, table_d)
        cos_inc = cos_table.copy()
        highlight = np.zeros((h, w), np.float32)
        ir_drop = np.zeros((h, w), np.float32)
        if part.any():
            rows, cols = np.nonzero(part)
            pts_w = (rays_c[rows, cols] * depth[rows, cols, None]) @ R.T + eye
            inst = instance[rows, cols]
            n_w = normals_w[rows, cols]
            n_w *= -np.sign(np.sum(n_w * (rays_c[rows, cols] @ R.T), axis=1) + 1e-12)[:, None]
            n_c = n_w @ R
            mats = shading.material_arrays([MATERIALS[o.material] for o in objects], inst,
                                           albedo_scale)
            lit_part = None
            if p.shadows:
                lit_part = lit_by_lamp(scene, pts_w, n_w, env.light)
                self._shadow_table(radiance, table_d, table_xy, part, T, intr.K, env, scene,
                                   meshes_w)
            shaded = shading.blinn_phong(pts_w, n_w, eye, mats['albedo'], mats['specular'],
                                         mats['shininess'], env.light, lit=lit_part,
                                         translucency=mats['translucency'])
            tl = mats['translucency']
            tint = mats['albedo'] / np.maximum(mats['albedo'].max(axis=1, keepdims=True), 1e-6)
            bleed = (0.4 * tl)[:, None]
            radiance[rows, cols] = ((1.0 - bleed) * shaded.radiance
                                    + bleed * radiance[rows, cols] * tint)
            highlight[rows, cols] = shaded.highlight
            ir_drop[rows, cols] = mats['ir_dropout']
            cos_inc[rows, cols] = np.abs(np.sum(n_c * rays_c[rows, cols], axis=1)
                                         * inv_len[rows, cols])
        rgb = shading.to_srgb8(radiance, env.exposure)
        t2 = time.perf_counter()
        self.timings['shading'] += t2 - t1

        noise_rng = self._rng(index, purpose, view_index)
        colour_sigma = p.colour_noise_sigma * min(p.noise_scale, 1.0)
        rgb = add_colour_noise(rgb, noise_rng, sigma=colour_sigma,
                               blur_sigma_px=p.blur_sigma_px)
        depth_mm = add_depth_noise(depth, intr.fx, noise_rng, p.depth_noise,
                                   cos_incidence=cos_inc, highlight=highlight,
                                   ir_dropout=ir_drop)
        t3 = time.perf_counter()
        self.timings['noise'] += t3 - t2

        gt = [self._ground_truth(k, obj, cam, instance, meshes_w[k], scene)
              for k, obj in enumerate(objects)]
        self.timings['gt'] += time.perf_counter() - t3
        return SimulatedView(cam.name, intr, T, rgb, depth_mm, depth, instance, gt)

    def _shadow_table(self, radiance: np.ndarray, table_d: np.ndarray, table_xy: np.ndarray,
                      part: np.ndarray, T: np.ndarray, intr_K: np.ndarray, env: _Environment,
                      occluders, meshes_w: list) -> None:
        """Darken the table where the parts cast shadows (rays only where a shadow can fall)."""
        light = np.asarray(env.light.position_w, np.float64)
        # Each part's shadow lies inside the box of its vertices projected from the lamp onto
        # z = 0; only table pixels in one of those boxes get a shadow ray.
        boxes = []
        for vertices, _ in meshes_w:
            v = vertices
            s = light[2] / np.maximum(light[2] - v[:, 2], 1e-6)
            xy = light[:2] + (v[:, :2] - light[:2]) * s[:, None]
            boxes.append((xy.min(axis=0), xy.max(axis=0)))
        table_free = (table_d > 0) & ~part
        h, w = table_d.shape
        T_cw = invert_transform(T)
        cand = np.zeros_like(table_free)
        for lo, hi in boxes:
            # Test table points only inside the image rectangle of the shadow box's corners.
            corners = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [lo[0], hi[1], 0],
                                [hi[0], hi[1], 0]])
            pts_c = transform_points(T_cw, corners)
            if np.any(pts_c[:, 2] <= 1e-3):
                r0, r1, c0, c1 = 0, h, 0, w
            else:
                uv = project_points(pts_c, intr_K)
                c0, r0 = np.clip(np.floor(uv.min(axis=0)).astype(int) - 1, 0, [w, h])
                c1, r1 = np.clip(np.ceil(uv.max(axis=0)).astype(int) + 2, 0, [w, h])
            x = table_xy[r0:r1, c0:c1, 0]
            y = table_xy[r0:r1, c0:c1, 1]
            cand[r0:r1, c0:c1] |= (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])
        cand &= table_free
        if not cand.any():
            return
        rows, cols = np.nonzero(cand)
        ground = np.zeros((len(rows), 3), np.float32)
        ground[:, :2] = table_xy[rows, cols]
        up = np.zeros_like(ground)
        up[:, 2] = 1.0
        lit = lit_by_lamp(occluders, ground, up, env.light)
        dark = lit < 1.0
        if dark.any():
            redo = shading.shade_table(env.table, ground[dark], T[:3, 3].astype(np.float32),
                                       env.light, lit=lit[dark])
            radiance[rows[dark], cols[dark]] = redo.radiance

    def _ground_truth(self, k: int, obj: PlacedObject, cam: CameraMount, instance: np.ndarray,
                      mesh_w: tuple[np.ndarray, np.ndarray], scene) -> GroundTruthObject:
        intr = cam.intrinsics
        T_cw = cam.T_camera_world
        mask = instance == k
        rows, cols = np.nonzero(mask)
        visib = int(len(rows))
        # The object alone: cast only the rays of its projected bounding box.
        pts_c = transform_points(T_cw, mesh_w[0])
        in_front = pts_c[:, 2] > 1e-3
        all_count, bbox_obj = 0, NO_BOX
        if in_front.any():
            uv = project_points(pts_c[in_front], intr.K)
            x0 = int(np.clip(np.floor(uv[:, 0].min()) - 1, 0, intr.width - 1))
            x1 = int(np.clip(np.ceil(uv[:, 0].max()) + 1, 0, intr.width - 1))
            y0 = int(np.clip(np.floor(uv[:, 1].min()) - 1, 0, intr.height - 1))
            y1 = int(np.clip(np.ceil(uv[:, 1].max()) + 1, 0, intr.height - 1))
            if x1 >= x0 and y1 >= y0:
                # Rays of the box whose first hit is this part, plus those that meet it behind
                # another part (cast against this part alone); rays that hit no part at all
                # cannot meet it.
                box_inst = instance[y0:y1 + 1, x0:x1 + 1]
                alone = box_inst == k
                rest = np.nonzero((box_inst >= 0) & ~alone)
                if len(rest[0]):
                    rays_c = shading.camera_rays(intr)[rest[0] + y0, rest[1] + x0]
                    T_wc = cam.T_world_camera.astype(np.float32)
                    origins = np.broadcast_to(T_wc[:3, 3], rays_c.shape)
                    behind = scene.hits(k, origins, rays_c @ T_wc[:3, :3].T)
                    alone[rest[0][behind], rest[1][behind]] = True
                hr, hc = np.nonzero(alone)
                all_count = int(len(hr))
                bbox_obj = _box(hr + y0, hc + x0)
        all_count = max(all_count, visib)
        return GroundTruthObject(
            obj_id=obj.obj_id, T_camera_object=T_cw @ obj.T_world_object,
            bbox_visib=_box(rows, cols), visib_fract=visib / all_count if all_count else 0.0,
            mask_visib=mask, px_count_all=all_count, px_count_visib=visib, bbox_obj=bbox_obj)
