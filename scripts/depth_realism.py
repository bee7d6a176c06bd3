"""How real-like is a depth image: noise on the table, its correlation length, edge spread,
holes. For simulated scenes (BOP folders of ``tlessbot simulate``) and the real RealSense
frames in ../shared/data (docs/bench/smoothed-sim-depth.md).

    PYTHONPATH=. python scripts/depth_realism.py --real ../shared/data \\
        --synthetic per_pixel smoothed --scenes SIMULATED_SCENES... --frames 5

Per image: the table plane (``find_table_plane``, the pipeline's own fit) and its noise
(``noise_at_1m_m``: 1.48 median |residual| / z²; at the plane's mean depth too); the residual
on the table (a quadratic in the image removed, parts and edges eroded away) and its
autocorrelation along rows and columns: the lag (px) where it falls below 0.5; the edge
spread: at every depth step of more than ``--jump-mm`` along a row or column (no hole within
8 px, well above the slope of the surfaces on either side), the step over its steepest single
pixel difference (1 = sharp), also in bins of the step's disparity (px); holes: the share of
pixels without depth, and of those in a 7x7 window whose valid depths span more than
``--jump-mm`` (at steps).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core.common.table_plane import find_table_plane


def _table_residual(depth_m: np.ndarray, K: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray]:
    """Plane noise figures, the residual image (m) and the mask of table pixels it holds."""
    plane = find_table_plane(depth_m, K)
    if plane is None:
        return {}, np.zeros_like(depth_m), np.zeros(depth_m.shape, bool)
    h, w = depth_m.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)],
                    axis=-1)
    distance = (rays @ plane.plane[:3]) * depth_m + plane.plane[3]
    noise = float(plane.noise_at_1m_m or 0.0)
    table = (depth_m > 0) & (np.abs(distance) < 3.0 * max(noise, 1e-3) * depth_m ** 2)
    table = cv2.erode(table.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    # a quadratic takes out a table that is not quite flat and the fit's small tilt errors
    uu, vv = (u[table] - w / 2) / w, (v[table] - h / 2) / h
    basis = np.stack([np.ones_like(uu), uu, vv, uu * uu, vv * vv, uu * vv], axis=1)
    coef, *_ = np.linalg.lstsq(basis, distance[table], rcond=None)
    residual = np.zeros_like(depth_m)
    residual[table] = distance[table] - basis @ coef
    z = float(depth_m[table].mean()) if table.any() else 0.0
    return {'plane_noise_1m_mm': 1000 * noise, 'table_z_m': z,
            'table_sigma_mm': 1000 * float(residual[table].std()),
            'table_share': float(table.mean())}, residual, table


def _correlation_length(residual: np.ndarray, mask: np.ndarray, axis: int,
                        max_lag: int = 40) -> float:
    """Lag (px, interpolated) where the masked autocorrelation along ``axis`` falls below 0.5."""
    r = np.where(mask, residual - residual[mask].mean(), 0.0)
    m = mask.astype(float)
    var = float((r * r).sum() / m.sum())
    previous = 1.0
    for lag in range(1, max_lag + 1):
        a = r[:, :-lag] * r[:, lag:] if axis == 1 else r[:-lag] * r[lag:]
        n = m[:, :-lag] * m[:, lag:] if axis == 1 else m[:-lag] * m[lag:]
        rho = float(a.sum() / max(n.sum(), 1.0) / var)
        if rho < 0.5:
            return lag - 1 + (previous - 0.5) / max(previous - rho, 1e-9)
        previous = rho
    return float(max_lag)


def _edge_spreads(depth_m: np.ndarray, jump_m: float, max_jump_m: float = np.inf,
                  half_px: int = 8) -> np.ndarray:
    """Ramp widths (px) of the depth steps along the rows: the step over its steepest single
    pixel difference (1 for a sharp step, ~2.5 sigma for a Gaussian blur of sigma px); slopes
    of the surfaces on either side barely change it."""
    widths = []
    k = half_px
    for row in depth_m:
        step = np.abs(row[2:] - row[:-2])              # central difference at u = 1 .. w-2
        for u in np.nonzero(step > jump_m / 4)[0] + 1:
            if u < k + 1 or u + k + 1 >= len(row):
                continue
            window = row[u - k:u + k + 1]
            if (window <= 0).any() or np.argmax(np.abs(window[2:] - window[:-2])) != k - 1:
                continue
            jump = abs(float(window[-3:].mean() - window[:3].mean()))
            # a steady slope is no edge: the step must be well above the sides' own slopes
            side_slope = max(abs(window[3] - window[0]), abs(window[-1] - window[-4])) / 3
            if jump_m <= jump < max_jump_m and jump >= 3 * k * side_slope:
                widths.append(jump / float(np.abs(np.diff(window)).max()))
    return np.asarray(widths, float)


def _holes_at_steps(depth_m: np.ndarray, jump_m: float) -> float:
    """Share of holes among the pixels whose 7x7 window spans a depth step."""
    window = np.ones((7, 7), np.uint8)
    valid = depth_m > 0
    high = cv2.dilate(np.where(valid, depth_m, 0).astype(np.float32), window)
    low = cv2.erode(np.where(valid, depth_m, 1e3).astype(np.float32), window)
    at_step = (high > 0) & (high - low > jump_m)
    return float((~valid[at_step]).mean()) if at_step.any() else float('nan')


DISPARITY_BINS_PX = ((0.3, 0.6), (0.6, 1.0), (1.0, 2.0))


def measure(depth_m: np.ndarray, K: np.ndarray, jump_m: float, fb_px_m: float) -> dict:
    """All figures of one depth image (metres, 0 = hole); ``fb_px_m``: the depth camera's IR
    focal length times its baseline (disparity = fb / z)."""
    figures, residual, table = _table_residual(depth_m, K)
    if figures:   # the height's noise as disparity (px), along the table's normal
        figures['disparity_sigma_px'] = figures['table_sigma_mm'] * 1e-3 * fb_px_m \
            / figures['table_z_m'] ** 2
    if table.sum() > 1000:
        figures['corr_row_px'] = _correlation_length(residual, table, 1)
        figures['corr_col_px'] = _correlation_length(residual, table, 0)
    spreads = np.concatenate([_edge_spreads(depth_m, jump_m), _edge_spreads(depth_m.T, jump_m)])
    figures['edges'] = len(spreads)
    figures['edge_spread_px'] = float(np.median(spreads)) if len(spreads) else float('nan')
    # the same in bins of the step's disparity: what the camera's smoothing keeps depends on it
    z2 = float(np.median(depth_m[depth_m > 0])) ** 2
    for low, high in DISPARITY_BINS_PX:
        bounds = (low * z2 / fb_px_m, high * z2 / fb_px_m)
        spreads = np.concatenate([_edge_spreads(depth_m, *bounds),
                                  _edge_spreads(depth_m.T, *bounds)])
        figures[f'spread_{low}-{high}px'] = \
            float(np.median(spreads)) if len(spreads) else float('nan')
    figures['holes'] = float((depth_m <= 0).mean())
    figures['holes_at_steps'] = _holes_at_steps(depth_m, jump_m)
    return figures


# D435: 50 mm baseline, IR focal 382 px at 640 x 480 (the visp set's unaligned depth camera)
D435_FB = 382.0 * 0.050


def _real_images(root: Path):
    """(name, depth m, K, fb) of the real RealSense depth images under ``root``."""
    sygrid = root / 'sygrid_real_d435i'
    cam = json.loads((sygrid / 'camera.json').read_text())
    K = np.array([[cam['fx'], 0, cam['cx']], [0, cam['fy'], cam['cy']], [0, 0, 1]])
    for name in sorted((sygrid / 'test' / '000001' / 'depth').glob('*.png')):
        depth = cv2.imread(str(name), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
        yield f'real D435i sygrid {name.stem}', depth, K, D435_FB
    folder = root / 'visp_realsense_tutorial_data' / 'computer-vision' / 'd435_align_depth'
    raw = (folder / 'depth_image_0000.bin').read_bytes()
    h, w = np.frombuffer(raw[:8], '<u4')
    depth = np.frombuffer(raw[8:], '<u2').reshape(h, w).astype(np.float32) / 1000.0
    K = np.array([[605.1467, 0, 325.5325], [0, 604.7915, 244.9508], [0, 0, 1]])
    yield 'real D435 visp align', depth, K, D435_FB
    # a desk seen from about 1 m: the top camera's distance (the camera model is not given)
    rbt = root / 'visp_images_rbt_sequence' / 'sequence'
    cam = json.loads((rbt / 'cam.json').read_text())
    K = np.array([[cam['px'], 0, cam['u0']], [0, cam['py'], cam['v0']], [0, 0, 1]])
    for name in sorted(rbt.glob('depth_image_*.npz')):
        with np.load(name, allow_pickle=False) as npz:
            depth = npz['data'].astype(np.float32) * float(cam['depthScale'])
        yield f'real visp rbt desk {name.stem[-4:]}', depth, K, D435_FB


def _scene_images(scenes: Path, frames: int, sim_fb: float):
    """(name, depth m, K, fb) of the first ``frames`` images of each camera of a BOP folder."""
    for camera in sorted(scenes.glob('test_*')):
        folder = camera / '000000'
        info = json.loads((folder / 'scene_camera.json').read_text())
        for key in sorted(info, key=int)[:frames]:
            path = folder / 'depth' / f'{int(key):06d}.png'
            scale = float(info[key].get('depth_scale', 1.0))
            depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float32) * scale / 1000
            K = np.array(info[key]['cam_K'], float).reshape(3, 3)
            yield f'{scenes} {camera.name}', depth, K, sim_fb


def _synthetic_images(kinds: list[str]):
    """(name, depth m, K, fb) of a table 30 degrees off the view at 0.36 m with a 20 mm box on
    it, seen as the real D435i frames are (their K, the D435's IR focal and baseline), through
    each depth model: pixel lengths and noise comparable with the real frames."""
    from tlessbot_ros.sim.noise import DepthNoiseParams, add_depth_noise

    K = np.array([[608.56, 0, 310.26], [0, 608.56, 238.32], [0, 0, 1]])
    u, v = np.meshgrid(np.arange(640), np.arange(480))
    z = (0.36 / (1 + np.tan(np.radians(30)) * (v - K[1, 2]) / K[1, 1])).astype(np.float32)
    z[(abs(u - 320) < 60) & (abs(v - 240) < 40)] -= 0.02
    for kind in kinds:
        params = DepthNoiseParams(kind=kind, ir_focal_px=382.0, baseline_m=0.05)
        depth = add_depth_noise(z, K[0, 0], np.random.default_rng(0), params)
        yield f'synthetic D435i view, {kind}', depth.astype(np.float32) / 1000, K, D435_FB


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--real', type=Path, help='the shared data folder (../shared/data)')
    parser.add_argument('--scenes', type=Path, nargs='*', default=[])
    parser.add_argument('--synthetic', nargs='*', default=[], choices=('per_pixel', 'smoothed'),
                        help='also a table and box rendered as the real D435i sees them')
    parser.add_argument('--frames', type=int, default=5)
    parser.add_argument('--jump-mm', type=float, default=8.0)
    parser.add_argument('--sim-fb', type=float, default=615.0 * 0.055,
                        help='IR focal (px) x baseline (m) of the simulated camera (D415)')
    args = parser.parse_args()
    images = list(_real_images(args.real)) if args.real else []
    images += list(_synthetic_images(args.synthetic))
    for scenes in args.scenes:
        images += list(_scene_images(scenes, args.frames, args.sim_fb))
    keys = ('plane_noise_1m_mm', 'table_z_m', 'table_sigma_mm', 'disparity_sigma_px',
            'corr_row_px', 'corr_col_px',
            'edge_spread_px', 'edges', *(f'spread_{a}-{b}px' for a, b in DISPARITY_BINS_PX),
            'holes', 'holes_at_steps')
    groups: dict[str, list[dict]] = {}
    for name, depth, K, fb in images:
        groups.setdefault(name, []).append(measure(depth, K, args.jump_mm * 1e-3, fb))
    print('| depth | images | ' + ' | '.join(keys) + ' |')
    print('|---|---:|' + '---:|' * len(keys))
    for name, rows in groups.items():
        cells = [f'{np.nanmedian([r.get(k, np.nan) for r in rows]):.3g}' for k in keys]
        print(f'| {name} | {len(rows)} | ' + ' | '.join(cells) + ' |')


if __name__ == '__main__':
    main()
