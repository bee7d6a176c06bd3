"""Two-view scenes from a renderer that is not ours (issue 41), in the dataset layout of
``tlessbot simulate``, so that ``tlessbot evaluate --dataset OUT --models MODELS`` scores them.

    MUJOCO_GL=egl PYTHONPATH=DIR python scripts/other_renderer_scenes.py \\
        --models ../shared/data/tless_models_cad_stl --ids 2 5 8 11 14 19 25 30 \\
        --out other/4100-T --frames 20 --seed 4100

(DIR: where requirements/bench-render.txt is installed, e.g. ``pip install --target DIR
--no-deps -r requirements/bench-render.txt``.) Nothing of tlessbot_ros.sim is used:

* physics: MuJoCo drops 3-8 parts (distinct classes) from random attitudes onto the table, some
  above others; parts collide by their meshes' convex hulls. The settled poses are the truth. A
  part that settles outside a camera's image (8 px margin) is taken out and the drop rerun.
* colour: MuJoCo's OpenGL renderer (offscreen, EGL or OSMesa): 2-3 spot lights with shadows,
  plastic or metal-like materials (specular, reflective), a plain or textured table; then
  sensor noise and a slight blur.
* depth: MuJoCo's depth buffer through scripts/other_renderer_depth.py (a model of its own).
* ground truth: visible masks from MuJoCo's segmentation; ``px_count_all`` and ``bbox_obj`` from
  each part rendered alone (the others moved away), as BOP defines them.

Reused from the package, io only: ``load_rig`` (the cell YAML's rig), ``load_models`` (mesh
files), ``BopWriter`` / ``write_camera_json`` (the dataset files) and ``models_info_entry``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from other_renderer_depth import stereo_depth_mm  # noqa: E402

from tlessbot_ros.core.common import invert_transform  # noqa: E402
from tlessbot_ros.io.bop import BopWriter, write_camera_json  # noqa: E402
from tlessbot_ros.io.models import ObjectModel, load_models  # noqa: E402
from tlessbot_ros.tools.support.models_info import (  # noqa: E402
    model_symmetries,
    models_info_entry,
)
from tlessbot_ros.tools.support.rig import load_rig  # noqa: E402

NO_BOX = (-1, -1, -1, -1)
AWAY_M = 50.0   # where a part goes while another one is rendered alone
HIGHLIGHT = 235   # grey level (every channel) of a highlight on a metal part


@dataclass(frozen=True)
class DropParams:
    """How the parts are dropped and drawn."""

    parts_min: int = 3
    parts_max: int = 8
    # drop points are drawn in a disc of this radius (m) round the work area's centre
    area_radius_m: float = 0.11
    # the chance that a part is dropped right above one dropped before it (a pile)
    stack_prob: float = 0.35
    # drop every part clear of the others' bounding spheres (no piles; they may still roll
    # against each other), in a disc of apart_radius_m
    apart: bool = False
    apart_radius_m: float = 0.16
    # simulated time allowed to settle (s), and the speed (m/s, rad/s) counted as at rest
    settle_s: float = 4.0
    rest_speed: float = 2e-3
    # a part must lie this far (px) inside both images, else it is taken out
    margin_px: int = 8
    # plastic density (kg/m^3) and sliding friction of parts and table
    density: float = 1200.0
    friction: float = 0.7
    # chance that a part gets a metal-like material, and that the table is textured
    metal_prob: float = 0.3
    textured_table_prob: float = 0.5
    # 'stereo': the depth model of other_renderer_depth.py; 'clean': the rendered depth, mm
    depth: str = 'stereo'
    # colour sensor noise (grey levels RMS) and blur (px)
    colour_noise: float = 2.0
    blur_sigma_px: float = 0.5


@dataclass
class View:
    """One camera's image of a frame, as io.bop.BopWriter.add reads it."""

    intrinsics: object
    T_world_camera: np.ndarray
    rgb: np.ndarray
    depth_mm: np.ndarray
    gt: list = field(default_factory=list)


def _mujoco():
    try:
        import mujoco
    except ImportError:
        raise SystemExit('other_renderer_scenes: needs mujoco (requirements/bench-render.txt) '
                         'and MUJOCO_GL=egl or osmesa') from None
    return mujoco


# --- the MuJoCo model ---------------------------------------------------------------------------

def _camera_quat(T_world_camera: np.ndarray) -> np.ndarray:
    """MuJoCo camera orientation (w, x, y, z) of an optical frame (x right, y down, z ahead):
    a MuJoCo camera looks along its -z with y up."""
    mujoco = _mujoco()
    R = T_world_camera[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, R.ravel())
    return quat


def _add_cameras(spec, rig) -> None:
    for name, cam in rig.cameras.items():
        K, (w, h) = cam.intrinsics.K, (cam.intrinsics.width, cam.intrinsics.height)
        if abs(K[0, 2] - (w - 1) / 2) > 0.5 or abs(K[1, 2] - (h - 1) / 2) > 0.5 \
                or abs(K[0, 0] - K[1, 1]) > 1e-6:
            raise SystemExit(f'camera {name}: MuJoCo cameras here want square pixels and the '
                             'principal point at the image centre')
        spec.worldbody.add_camera(name=name, pos=cam.T_world_camera[:3, 3],
                                  quat=_camera_quat(cam.T_world_camera),
                                  fovy=float(np.degrees(2 * np.arctan(h / 2 / K[1, 1]))))


def _add_table(spec, rng: np.random.Generator, params: DropParams) -> str:
    mujoco = _mujoco()
    base = rng.uniform(0.25, 0.75) * rng.uniform(0.8, 1.0, 3)
    material = spec.add_material(name='table', rgba=[*base, 1.0], specular=0.1,
                                 shininess=0.2)
    kind = 'plain'
    if rng.random() < params.textured_table_prob:
        kind = ['checker', 'speckled'][int(rng.integers(2))]
        builtin = (mujoco.mjtBuiltin.mjBUILTIN_CHECKER if kind == 'checker'
                   else mujoco.mjtBuiltin.mjBUILTIN_FLAT)
        spec.add_texture(name='table', type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=builtin,
                         rgb1=base, rgb2=np.clip(base * rng.uniform(0.6, 1.3, 3), 0, 1),
                         mark=mujoco.mjtMark.mjMARK_RANDOM, random=0.05,
                         markrgb=np.clip(base * 0.7, 0, 1), width=512, height=512)
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = 'table'
        material.texrepeat = [float(rng.uniform(2, 8))] * 2
        material.rgba = [1.0, 1.0, 1.0, 1.0]
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1.0, 1.0, 0.01],
                            material='table', friction=[params.friction, 0.005, 0.0001])
    return kind


def _add_lights(spec, rng: np.random.Generator) -> None:
    spec.visual.headlight.ambient = [0.15] * 3
    spec.visual.headlight.diffuse = [0.15] * 3
    spec.visual.headlight.specular = [0.05] * 3
    for k in range(int(rng.integers(2, 4))):
        azimuth, elevation = rng.uniform(0, 2 * np.pi), rng.uniform(np.radians(35), np.radians(80))
        distance = rng.uniform(1.0, 2.0)
        pos = distance * np.array([np.cos(azimuth) * np.cos(elevation),
                                   np.sin(azimuth) * np.cos(elevation), np.sin(elevation)])
        spec.worldbody.add_light(name=f'lamp{k}', pos=pos, dir=-pos / np.linalg.norm(pos),
                                 castshadow=bool(k == 0 or rng.random() < 0.5), cutoff=60,
                                 diffuse=[rng.uniform(0.35, 0.7)] * 3, specular=[0.4] * 3)


def _part_material(spec, name: str, rng: np.random.Generator, params: DropParams) -> str:
    if rng.random() < params.metal_prob:   # brushed steel or aluminium: grey, shiny
        grey = rng.uniform(0.45, 0.75)
        spec.add_material(name=name, rgba=[grey, grey, grey * rng.uniform(0.95, 1.05), 1],
                          specular=rng.uniform(0.7, 1.0), shininess=rng.uniform(0.6, 0.95),
                          reflectance=rng.uniform(0.1, 0.35))
        return 'metal'
    else:   # plastic, mostly light as T-LESS parts, some dark or coloured
        kind = rng.random()
        if kind < 0.55:
            rgb = rng.uniform(0.7, 0.9) * rng.uniform(0.92, 1.0, 3)
        elif kind < 0.8:
            rgb = rng.uniform(0.08, 0.25) * np.ones(3)
        else:
            rgb = rng.uniform(0.15, 0.9, 3)
        spec.add_material(name=name, rgba=[*rgb, 1], specular=rng.uniform(0.1, 0.5),
                          shininess=rng.uniform(0.1, 0.5))
        return ['light', 'dark', 'coloured'][(kind >= 0.55) + (kind >= 0.8)]


def build_model(models: dict[int, ObjectModel], ids: list[int], drops: list[np.ndarray],
                rig, rng: np.random.Generator, params: DropParams):
    """The MuJoCo model of one frame: table, lights, the rig's cameras and part k of ``ids``
    as body ``part{k}`` (a free body; its frame is the model's) at pose ``drops[k]``; and
    what was drawn: the table's kind and each part's material."""
    mujoco = _mujoco()
    spec = mujoco.MjSpec()
    spec.option.timestep = 0.002
    spec.stat.extent = 1.0
    spec.visual.map.znear = 0.02
    spec.visual.map.zfar = 10.0
    spec.visual.quality.shadowsize = 2048
    width = max(c.intrinsics.width for c in rig.cameras.values())
    height = max(c.intrinsics.height for c in rig.cameras.values())
    spec.visual.global_.offwidth, spec.visual.global_.offheight = width, height
    drawn = {'table': _add_table(spec, rng, params), 'materials': []}
    _add_lights(spec, rng)
    _add_cameras(spec, rig)
    for k, (obj_id, T) in enumerate(zip(ids, drops)):
        model = models[obj_id]
        spec.add_mesh(name=f'mesh{k}', uservert=model.vertices.ravel(),
                      userface=model.faces.ravel())
        drawn['materials'].append(_part_material(spec, f'part{k}', rng, params))
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, T[:3, :3].ravel())
        body = spec.worldbody.add_body(name=f'part{k}', pos=T[:3, 3], quat=quat)
        body.add_freejoint()
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f'mesh{k}',
                      material=f'part{k}', density=params.density,
                      friction=[params.friction, 0.005, 0.0001])
    return spec.compile(), drawn


# --- dropping -----------------------------------------------------------------------------------

def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _drop_point(rng: np.random.Generator, params: DropParams, radius: float,
                spheres: list[tuple[np.ndarray, float]]) -> np.ndarray:
    """(2,) a drop point in the work area; with ``apart``, clear of the spheres (50 tries)."""
    area = params.apart_radius_m if params.apart else params.area_radius_m
    for _ in range(50):
        r, a = area * np.sqrt(rng.random()), rng.uniform(0, 2 * np.pi)
        xy = np.array([r * np.cos(a), r * np.sin(a)])
        if not params.apart or all(np.linalg.norm(c[:2] - xy) > rc + radius
                                   for c, rc in spheres):
            break
    return xy


def drop_poses(models: dict[int, ObjectModel], ids: list[int], rng: np.random.Generator,
               params: DropParams) -> list[np.ndarray]:
    """Start poses (4, 4), model frame in world: random attitudes, bounding spheres apart;
    with ``stack_prob`` a part starts right above an earlier one."""
    poses: list[np.ndarray] = []
    spheres: list[tuple[np.ndarray, float]] = []   # (centre, radius) of each start
    for obj_id in ids:
        model = models[obj_id]
        R = _random_rotation(rng)
        centre_model = (model.vertices.min(0) + model.vertices.max(0)) / 2
        radius = float(np.linalg.norm(model.vertices - centre_model, axis=1).max())
        if spheres and not params.apart and rng.random() < params.stack_prob:
            xy = spheres[int(rng.integers(len(spheres)))][0][:2] + rng.normal(0, 0.01, 2)
        else:
            xy = _drop_point(rng, params, radius, spheres)
        z = radius + 0.005
        for c, rc in spheres:   # above every start it would touch
            if np.linalg.norm(c[:2] - xy) < rc + radius:
                z = max(z, c[2] + rc + radius + 0.005)
        centre = np.array([*xy, z])
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = centre - R @ centre_model
        poses.append(T)
        spheres.append((centre, radius))
    return poses


def settle(model, data, params: DropParams) -> bool:
    """Step until every part rests (0.2 s below ``rest_speed``); False if time ran out."""
    mujoco = _mujoco()
    still_steps, need = 0, int(0.2 / model.opt.timestep)
    for _ in range(int(params.settle_s / model.opt.timestep)):
        mujoco.mj_step(model, data)
        still_steps = still_steps + 1 if np.abs(data.qvel).max() < params.rest_speed else 0
        if still_steps >= need:
            return True
    return False


def body_poses(model, data, count: int) -> list[np.ndarray]:
    """(4, 4) world pose of body ``part{k}`` (the model's frame) for k < count."""
    poses = []
    for k in range(count):
        body = model.body(f'part{k}').id
        T = np.eye(4)
        T[:3, :3] = data.xmat[body].reshape(3, 3)
        T[:3, 3] = data.xpos[body]
        poses.append(T)
    return poses


def _inside_images(vertices_w: np.ndarray, rig, margin_px: int) -> bool:
    for cam in rig.cameras.values():
        p = (invert_transform(cam.T_world_camera) @ np.c_[vertices_w, np.ones(len(vertices_w))].T
             )[:3]
        if np.any(p[2] <= 0.05):
            return False
        uv = (cam.intrinsics.K @ p)[:2] / p[2]
        w, h = cam.intrinsics.width, cam.intrinsics.height
        if uv.min() < margin_px or uv[0].max() > w - 1 - margin_px \
                or uv[1].max() > h - 1 - margin_px:
            return False
    return True


def settled_frame(models: dict[int, ObjectModel], rig, rng: np.random.Generator,
                  params: DropParams):
    """(MuJoCo model, data, part ids, what was drawn) of one frame whose parts rest inside
    both images."""
    mujoco = _mujoco()
    count = int(rng.integers(params.parts_min, params.parts_max + 1))
    ids = [int(i) for i in rng.choice(sorted(models), size=min(count, len(models)),
                                      replace=False)]
    drops = drop_poses(models, ids, rng, params)
    seed = int(rng.integers(2**31))
    while True:
        model, drawn = build_model(models, ids, drops, rig, np.random.default_rng(seed),
                                   params)
        data = mujoco.MjData(model)
        settle(model, data, params)
        poses = body_poses(model, data, len(ids))
        keep = [k for k, T in enumerate(poses) if _inside_images(
            (T[:3, :3] @ models[ids[k]].vertices.T).T + T[:3, 3], rig, params.margin_px)]
        if len(keep) == len(ids):
            return model, data, ids, drawn
        if len(keep) < params.parts_min:   # too few left: a new drop of the same parts
            drops = drop_poses(models, ids, rng, params)
        else:
            ids, drops = [ids[k] for k in keep], [drops[k] for k in keep]


# --- rendering ----------------------------------------------------------------------------------

def _box(mask: np.ndarray) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return NO_BOX
    return (int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1),
            int(ys.max() - ys.min() + 1))


def _part_of_pixel(model, segmentation: np.ndarray, count: int) -> np.ndarray:
    """(H, W) index of the part each pixel shows, -1 for none."""
    mujoco = _mujoco()
    geom_part = np.full(model.ngeom + 1, -1, np.int32)
    for k in range(count):
        body = model.body(f'part{k}').id
        geom_part[np.nonzero(model.geom_bodyid == body)[0]] = k
    ids, kinds = segmentation[..., 0], segmentation[..., 1]
    is_geom = (kinds == int(mujoco.mjtObj.mjOBJ_GEOM)) & (ids >= 0)
    return np.where(is_geom, geom_part[np.where(is_geom, ids, model.ngeom)], -1)


def _alone_masks(renderer, model, data, camera: str, count: int) -> list[np.ndarray]:
    """Each part's pixels rendered with the other parts moved away (BOP's px_count_all)."""
    mujoco = _mujoco()
    kept = data.qpos.copy()
    masks = []
    for k in range(count):
        for j in range(count):
            if j != k:
                adr = model.jnt_qposadr[model.body_jntadr[model.body(f'part{j}').id]]
                data.qpos[adr:adr + 3] = [AWAY_M * (j + 1), AWAY_M, -AWAY_M]
        mujoco.mj_kinematics(model, data)
        renderer.update_scene(data, camera=camera)
        masks.append(_part_of_pixel(model, renderer.render(), count) == k)
        data.qpos[:] = kept
    mujoco.mj_kinematics(model, data)
    return masks


def _metal_parts(model, count: int) -> np.ndarray:
    """(count,) bool: part k has a metal-like (reflective) material."""
    metal = np.zeros(count, bool)
    for k in range(count):
        geom = np.nonzero(model.geom_bodyid == model.body(f'part{k}').id)[0][0]
        metal[k] = model.mat_reflectance[model.geom_matid[geom]] > 0
    return metal


def _noisy_colour(rgb: np.ndarray, rng: np.random.Generator, params: DropParams) -> np.ndarray:
    image = rgb.astype(np.float32)
    if params.blur_sigma_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), params.blur_sigma_px)
    image += rng.normal(0, params.colour_noise, image.shape).astype(np.float32)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def render_view(model, data, cam, camera: str, ids: list[int], rng: np.random.Generator,
                params: DropParams) -> View:
    """Colour, depth and ground truth of one camera."""
    mujoco = _mujoco()
    width, height = cam.intrinsics.width, cam.intrinsics.height
    with mujoco.Renderer(model, height, width) as renderer:
        renderer.update_scene(data, camera=camera)
        rgb = renderer.render().copy()
        renderer.enable_depth_rendering()
        renderer.update_scene(data, camera=camera)
        z = renderer.render().copy()
        renderer.disable_depth_rendering()
        renderer.enable_segmentation_rendering()
        renderer.update_scene(data, camera=camera)
        visible = _part_of_pixel(model, renderer.render(), len(ids))
        alone = _alone_masks(renderer, model, data, camera, len(ids))
    metal = _metal_parts(model, len(ids))
    shiny = (visible >= 0) & metal[np.maximum(visible, 0)] & (rgb.min(axis=-1) >= HIGHLIGHT)
    rgb = _noisy_colour(rgb, rng, params)
    z = np.where(z < model.vis.map.zfar * 0.99, z, 0)
    depth_mm = (stereo_depth_mm(z, shiny, cam.intrinsics.K, rng) if params.depth == 'stereo'
                else np.clip(np.rint(z * 1000.0), 0, 65535).astype(np.uint16))
    view = View(cam.intrinsics, cam.T_world_camera, rgb, depth_mm)
    T_camera_world = invert_transform(cam.T_world_camera)
    for k, (obj_id, T) in enumerate(zip(ids, body_poses(model, data, len(ids)))):
        mask = visible == k
        count_all, count_visib = int(alone[k].sum()), int(mask.sum())
        view.gt.append(SimpleNamespace(
            obj_id=obj_id, T_camera_object=T_camera_world @ T, mask_visib=mask,
            bbox_visib=_box(mask), bbox_obj=_box(alone[k]), px_count_all=count_all,
            px_count_visib=count_visib,
            visib_fract=count_visib / count_all if count_all else 0.0))
    return view


# --- the command --------------------------------------------------------------------------------

def write_scenes(models: dict[int, ObjectModel], rig, out: Path, frames: int, seed: int,
                 params: DropParams) -> None:
    """Frames 0..frames-1 as scene 0 of test_<camera> for every camera of ``rig``."""
    out.mkdir(parents=True, exist_ok=True)
    writers = {name: BopWriter(out, f'test_{name}') for name in rig.cameras}
    for name, cam in rig.cameras.items():
        write_camera_json(out / f'camera_{name}.json', cam.intrinsics)
    (out / 'models_info.json').write_text(json.dumps(
        {str(i): models_info_entry(m, model_symmetries(m)) for i, m in models.items()},
        indent=1))
    drawn: dict[int, dict] = {}
    try:
        for index in range(frames):
            started = time.perf_counter()
            rng = np.random.default_rng([seed, index])
            model, data, ids, drawn[index] = settled_frame(models, rig, rng, params)
            for k, (name, cam) in enumerate(rig.cameras.items()):
                view = render_view(model, data, cam, name, ids,
                                   np.random.default_rng([seed, index, k + 1]), params)
                writers[name].add(0, index, view)
            print(f'frame {index}: {len(ids)} parts {ids} '
                  f'({time.perf_counter() - started:.1f} s)', flush=True)
    finally:
        for writer in writers.values():
            writer.close()
        # per frame: table kind and part materials (in scene_gt order), to sort misses by
        (out / 'other_renderer.json').write_text(json.dumps(drawn, indent=1))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--models', required=True, type=Path,
                        help='obj_NN.stl|ply|obj models (mm), as tlessbot simulate reads them')
    parser.add_argument('--ids', type=int, nargs='+', help='object ids to use (default: all)')
    parser.add_argument('--out', required=True, type=Path)
    parser.add_argument('--frames', type=int, default=20)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--parts-min', type=int, default=DropParams.parts_min)
    parser.add_argument('--parts-max', type=int, default=DropParams.parts_max)
    parser.add_argument('--stack-prob', type=float, default=DropParams.stack_prob,
                        help='chance that a part is dropped right above an earlier one')
    parser.add_argument('--apart', action='store_true',
                        help='drop the parts clear of each other (no piles)')
    parser.add_argument('--depth', choices=('stereo', 'clean'), default=DropParams.depth,
                        help='the depth model (default) or the rendered depth in mm (ablation)')
    parser.add_argument('--config', type=Path, help='cell YAML with the rig (config/cell.yaml)')
    parser.add_argument('--width', type=int, help="image width (default: the rig's)")
    parser.add_argument('--height', type=int, help="image height (default: the rig's)")
    args = parser.parse_args(argv)
    models = load_models(args.models, args.ids)
    rig = load_rig(args.config, width=args.width, height=args.height)
    params = DropParams(parts_min=args.parts_min, parts_max=args.parts_max,
                        stack_prob=args.stack_prob, apart=args.apart, depth=args.depth)
    write_scenes(models, rig, args.out, args.frames, args.seed, params)
    return 0


if __name__ == '__main__':
    sys.exit(main())
