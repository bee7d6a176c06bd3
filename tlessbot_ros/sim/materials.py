"""Materials of the printed parts and of the table, and the lighting of a simulated cell.

The parts are the paper's PLA prints (§4): light-yellow translucent, shiny pink, black and blue.
Colours are linear RGB reflectances in [0, 1]; the renderer applies a display gamma at the end.
Tables are procedural textures evaluated in world coordinates (metres on the table plane z = 0),
so both cameras see the same pattern in the same place.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Material:
    """Blinn-Phong material of a part.

    Attributes:
        name: short name used on the command line and in reports.
        albedo: (3,) linear RGB diffuse reflectance.
        specular: specular reflectance (0 = matte, ~0.6 = glossy PLA).
        shininess: Blinn-Phong exponent (larger = smaller, sharper highlights).
        translucency: 0..1; softens the Lambert falloff (wrap lighting), adds a subsurface glow
            and lets some of the background show through (light-yellow PLA).
        ir_dropout: extra probability of a depth hole where the part shows a strong highlight
            (shiny parts make the D415 stereo matcher fail).
    """

    name: str
    albedo: tuple[float, float, float]
    specular: float
    shininess: float
    translucency: float = 0.0
    ir_dropout: float = 0.0


LIGHT_YELLOW = Material('light_yellow', (0.80, 0.70, 0.32), specular=0.12, shininess=18.0,
                        translucency=0.45, ir_dropout=0.05)
SHINY_PINK = Material('pink', (0.78, 0.22, 0.42), specular=0.65, shininess=80.0,
                      translucency=0.05, ir_dropout=0.35)
BLACK = Material('black', (0.015, 0.015, 0.018), specular=0.30, shininess=45.0, ir_dropout=0.10)
BLUE = Material('blue', (0.05, 0.13, 0.55), specular=0.25, shininess=35.0, ir_dropout=0.08)

MATERIALS: dict[str, Material] = {m.name: m for m in (LIGHT_YELLOW, SHINY_PINK, BLACK, BLUE)}

TABLE_KINDS = ('plain', 'wood', 'checker')


@dataclass(frozen=True)
class Light:
    """A point light plus ambient light, in the world frame.

    ``intensity`` is the irradiance (relative units) the light gives at the table origin for a
    surface facing it; it falls off with the squared distance elsewhere.
    """

    position_w: tuple[float, float, float]
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = 1.0
    ambient: float = 0.25


@dataclass(frozen=True)
class Decal:
    """A flat print lying on the table (a calibration board): it replaces the table's albedo
    where it lies, and leaves the geometry (and so the depth) unchanged.

    Attributes:
        texture: (h, w) float32 linear grey albedo, row 0 at the print's top.
        table_to_texel: (2, 3) float64 affine map of table points (x, y, 1) in metres to
            texel coordinates (column, row), texel centres at integers.
    """

    texture: np.ndarray
    table_to_texel: np.ndarray


def _remap(texture: np.ndarray, map_x: np.ndarray, map_y: np.ndarray,
           border: int) -> np.ndarray:
    """``cv2.remap`` (bilinear) of (N,) float32 maps, folded into rows of 1024 because remap
    wants 2-D maps shorter than 32767 on each side; returns (N, channels...)."""
    import cv2

    cols = 1024
    pad = (-len(map_x)) % cols
    out = cv2.remap(texture, np.pad(map_x, (0, pad)).reshape(-1, cols),
                    np.pad(map_y, (0, pad)).reshape(-1, cols), cv2.INTER_LINEAR,
                    borderMode=border)
    return out.reshape(-1, *texture.shape[2:])[:len(map_x)]


@dataclass
class Table:
    """A table surface: albedo texture covering ``[-half_size_m, half_size_m]^2`` of the plane.

    ``texture`` is (N, N, 3) float32 linear RGB, row index along -y (image-like), column along x.
    ``decal`` is a print lying on it (None: the bare table).
    """

    kind: str
    texture: np.ndarray
    half_size_m: float = 0.8
    specular: float = 0.04
    shininess: float = 10.0
    extra: dict = field(default_factory=dict)
    decal: Decal | None = None

    def albedo_at(self, xy_w: np.ndarray) -> np.ndarray:
        """Albedo (..., 3) at table points (..., 2) in metres (clamped at the texture border)."""
        import cv2

        n = self.texture.shape[0]
        scale = (n - 1) / (2.0 * self.half_size_m)
        map_x = ((xy_w[..., 0] + self.half_size_m) * scale).astype(np.float32)
        map_y = ((self.half_size_m - xy_w[..., 1]) * scale).astype(np.float32)
        shape = map_x.shape
        out = _remap(self.texture, map_x.reshape(-1), map_y.reshape(-1), cv2.BORDER_REFLECT)
        if self.decal is not None:
            self._apply_decal(out, xy_w.reshape(-1, 2))
        return out.reshape(*shape, 3)

    def _apply_decal(self, albedo: np.ndarray, xy_w: np.ndarray) -> None:
        """Replace (N, 3) ``albedo`` by the decal's where the (N, 2) points lie on it."""
        import cv2

        decal = self.decal
        h, w = decal.texture.shape
        A = decal.table_to_texel
        u = xy_w @ A[:, :2].T + A[:, 2]
        # Texel centres are at integers: the print covers [-0.5, size - 0.5].
        on = (u[:, 0] >= -0.5) & (u[:, 0] <= w - 0.5) & (u[:, 1] >= -0.5) & (u[:, 1] <= h - 0.5)
        if on.any():
            u = u[on].astype(np.float32)
            grey = _remap(decal.texture, u[:, 0].copy(), u[:, 1].copy(), cv2.BORDER_REPLICATE)
            albedo[on] = grey[:, None]


def _smooth_noise(rng: np.random.Generator, n: int, cells: int) -> np.ndarray:
    """(n, n) float32 value noise in [-1, 1] with about ``cells`` features across."""
    import cv2

    coarse = rng.uniform(-1.0, 1.0, (cells + 1, cells + 1)).astype(np.float32)
    return cv2.resize(coarse, (n, n), interpolation=cv2.INTER_CUBIC)


def make_table(kind: str, rng: np.random.Generator, *, size_px: int = 512,
               half_size_m: float = 0.8) -> Table:
    """A random table of ``kind`` ('plain', 'wood' or 'checker') drawn from ``rng``."""
    if kind not in TABLE_KINDS:
        raise ValueError(f'unknown table kind {kind!r}; choose from {TABLE_KINDS}')
    n = size_px
    x = np.linspace(-half_size_m, half_size_m, n, dtype=np.float32)
    X, Y = np.meshgrid(x, -x)
    if kind == 'plain':
        grey = rng.uniform(0.35, 0.75)
        tint = 1.0 + rng.uniform(-0.05, 0.05, 3)
        base = np.clip(grey * tint, 0, 1).astype(np.float32)
        mottle = 1.0 + 0.03 * _smooth_noise(rng, n, 40)
        texture = base[None, None, :] * mottle[..., None]
    elif kind == 'wood':
        base = np.array([0.45, 0.27, 0.12]) * rng.uniform(0.7, 1.2)
        angle = rng.uniform(0, np.pi)
        u = X * np.cos(angle) + Y * np.sin(angle)
        warp = 0.012 * _smooth_noise(rng, n, 12)
        rings = 0.5 + 0.5 * np.sin(2 * np.pi * (u + warp) / rng.uniform(0.008, 0.02))
        streak = 0.5 + 0.5 * _smooth_noise(rng, n, 60)
        shade = 0.70 + 0.22 * rings ** 2 + 0.08 * streak
        texture = np.clip(base[None, None, :] * shade[..., None], 0, 1)
    else:  # checker
        square = rng.uniform(0.03, 0.08)
        light, dark = rng.uniform(0.55, 0.8), rng.uniform(0.08, 0.25)
        cells = (np.floor(X / square) + np.floor(Y / square)) % 2
        grey = np.where(cells > 0, light, dark)
        tint = 1.0 + rng.uniform(-0.08, 0.08, 3)
        texture = np.clip(grey[..., None] * tint[None, None, :], 0, 1)
    return Table(kind, np.ascontiguousarray(texture, dtype=np.float32), half_size_m)


def random_light(rng: np.random.Generator) -> Light:
    """A ceiling lamp somewhere above the work area, with random brightness, tint and ambient."""
    position = (rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), rng.uniform(1.2, 2.4))
    warmth = rng.uniform(-0.08, 0.08)
    colour = (1.0 + warmth, 1.0, 1.0 - warmth)
    return Light(position, colour, intensity=float(rng.uniform(0.7, 1.3)),
                 ambient=float(rng.uniform(0.12, 0.35)))
