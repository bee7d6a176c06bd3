"""The analytic warm-up frame: table pixels lie on z = 0, box pixels on the box."""
import numpy as np

from tlessbot_ros.core.common import default_rig, depth_to_points, table_with_box, transform_points


def test_every_pixel_lies_on_the_table_or_on_the_box():
    for camera in default_rig().cameras.values():
        rgb, depth, box = table_with_box(camera.intrinsics, camera.T_world_camera,
                                         box_size_m=(0.06, 0.04, 0.03))
        assert rgb.shape == (480, 640, 3) and depth.dtype == np.float32
        assert 100 < box.sum() < 0.2 * box.size
        for mask, check in ((box, 'box'), (~box, 'table')):
            points, _ = depth_to_points(depth, camera.intrinsics.K, mask=mask)
            world = transform_points(camera.T_world_camera, points.astype(np.float64))
            if check == 'table':
                assert np.abs(world[:, 2]).max() < 1e-4
            else:
                inside = (np.abs(world[:, 0]) <= 0.03 + 1e-4) & (np.abs(world[:, 1]) <= 0.02
                                                                 + 1e-4)
                assert inside.all() and world[:, 2].min() > -1e-4
                assert world[:, 2].max() < 0.03 + 1e-4
