import numpy as np

from tlessbot_ros.sim.materials import Light, make_table
from tlessbot_ros.sim.shading import blinn_phong, to_srgb8


def test_lambert_and_highlight():
    light = Light((0.0, 0.0, 2.0), ambient=0.0)
    pts = np.zeros((3, 3), np.float32)
    normals = np.array([[0, 0, 1], [np.sin(1.0), 0, np.cos(1.0)], [1, 0, 0]], np.float32)
    ones = np.ones((3, 3), np.float32)
    out = blinn_phong(pts, normals, np.array([0, 0, 1.0], np.float32), ones,
                      np.zeros(3, np.float32), np.full(3, 10, np.float32), light)
    assert np.allclose(out.radiance[:, 0], [1.0, np.cos(1.0), 0.0], atol=1e-5)
    assert out.highlight[0] == 1.0 and out.highlight[2] == 0.0


def test_gamma_and_tables():
    x = np.linspace(0, 1.2, 50, dtype=np.float32)[:, None].repeat(3, 1)
    y = to_srgb8(x)
    assert y[0, 0] == 0 and y[-1, 0] == 255 and np.all(np.diff(y[:, 0].astype(int)) >= 0)
    rng = np.random.default_rng(0)
    for kind in ('plain', 'wood', 'checker'):
        table = make_table(kind, rng)
        albedo = table.albedo_at(np.array([[0.0, 0.0], [0.1, 0.05]]))
        assert albedo.shape == (2, 3) and np.all((albedo >= 0) & (albedo <= 1))


def test_shade_render_of_a_core_render(tless_models_dir):
    from tlessbot_ros.core.common import MeshRenderer, default_rig
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.materials import BLACK, LIGHT_YELLOW, Light
    from tlessbot_ros.sim.shading import shade_render

    model = load_models(tless_models_dir, ids=[6])[6]
    cam = default_rig(160, 120)['side']
    T = np.eye(4)
    T[2, 3] = 0.03
    renderer = MeshRenderer()
    renderer.add_mesh(model.vertices, model.faces, T)
    result = renderer.render(cam.intrinsics, cam.T_world_camera)
    light = Light((0.3, -0.5, 1.5))
    grey = np.full((120, 160, 3), 0.2, np.float32)
    yellow = shade_render(result, cam.T_world_camera, [LIGHT_YELLOW], light, background=grey)
    black = shade_render(result, cam.T_world_camera, [BLACK], light, background=grey)
    part = result.instance == 0
    assert part.sum() > 100 and yellow.dtype == np.uint8
    assert np.array_equal(yellow[~part], black[~part])  # background untouched
    assert yellow[part].mean() > black[part].mean() + 60
