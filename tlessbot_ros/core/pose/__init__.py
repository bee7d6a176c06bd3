"""Stage 3, pose: region clouds, the template database, the table-plane and RANSAC pose
searches with their refinement, and the look-alike check.

This package's public API; names load on first use, so importing one light module
(geometry, say) does not import Open3D."""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

# name -> the module of this package that defines it
_HOME = {
    'PointBuckets': 'buckets',
    'CloudParams': 'cloud',
    'crop_box': 'cloud',
    'estimate_normals': 'cloud',
    'fit_plane': 'cloud',
    'preprocess_roi': 'cloud',
    'remove_statistical_outliers': 'cloud',
    'rgbd_to_cloud': 'cloud',
    'roi_cloud': 'cloud',
    'subtract_background': 'cloud',
    'to_o3d': 'cloud',
    'voxel_downsample': 'cloud',
    'COVERAGE_WEIGHT': 'estimator',
    'METHODS': 'estimator',
    'PoseCandidate': 'estimator',
    'PoseEstimator': 'estimator',
    'PoseParams': 'estimator',
    'PoseResult': 'estimator',
    'register_templates': 'estimator',
    'table_frame_from_plane': 'estimator',
    'gauss_newton': 'grid_kernels',
    'inlier_fraction': 'grid_kernels',
    'normal_equations': 'grid_kernels',
    'self_visible': 'grid_kernels',
    'truncated_cost': 'grid_kernels',
    'LookalikeCheck': 'lookalike',
    'MISS_ERROR_M': 'lookalike',
    'Mesh': 'lookalike',
    'depth_errors': 'lookalike',
    'depth_vote': 'lookalike',
    'lookalike_pairs': 'lookalike',
    'shared_surface': 'lookalike',
    'visible_difference': 'lookalike',
    'CONTINUOUS_YAW_PERIOD': 'templates',
    'FORMAT': 'templates',
    'NORMAL_SCALE': 'templates',
    'NearestGrid': 'templates',
    'ObjectTemplates': 'templates',
    'POINT_QUANTUM_M': 'templates',
    'READABLE_VERSIONS': 'templates',
    'Template': 'templates',
    'TemplateDatabase': 'templates',
    'TemplateParams': 'templates',
    'VERSION': 'templates',
    'build_database': 'templates',
    'build_object_templates': 'templates',
    'compute_fpfh': 'templates',
    'diameter': 'templates',
    'merge_equivalent_poses': 'templates',
    'resting_pose': 'templates',
    'sample_surface': 'templates',
    'template_from_cloud': 'templates',
    'yaw_period': 'templates',
}
__all__ = sorted(_HOME)


def __getattr__(name: str):
    try:
        module = _HOME[name]
    except KeyError:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}') from None
    value = getattr(importlib.import_module(f'{__name__}.{module}'), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:
    from tlessbot_ros.core.pose.buckets import (  # noqa: F401
        PointBuckets,
    )
    from tlessbot_ros.core.pose.cloud import (  # noqa: F401
        CloudParams,
        crop_box,
        estimate_normals,
        fit_plane,
        preprocess_roi,
        remove_statistical_outliers,
        rgbd_to_cloud,
        roi_cloud,
        subtract_background,
        to_o3d,
        voxel_downsample,
    )
    from tlessbot_ros.core.pose.estimator import (  # noqa: F401
        COVERAGE_WEIGHT,
        METHODS,
        PoseCandidate,
        PoseEstimator,
        PoseParams,
        PoseResult,
        register_templates,
        table_frame_from_plane,
    )
    from tlessbot_ros.core.pose.grid_kernels import (  # noqa: F401
        gauss_newton,
        inlier_fraction,
        normal_equations,
        self_visible,
        truncated_cost,
    )
    from tlessbot_ros.core.pose.lookalike import (  # noqa: F401
        MISS_ERROR_M,
        LookalikeCheck,
        Mesh,
        depth_errors,
        depth_vote,
        lookalike_pairs,
        shared_surface,
        visible_difference,
    )
    from tlessbot_ros.core.pose.templates import (  # noqa: F401
        CONTINUOUS_YAW_PERIOD,
        FORMAT,
        NORMAL_SCALE,
        POINT_QUANTUM_M,
        READABLE_VERSIONS,
        VERSION,
        NearestGrid,
        ObjectTemplates,
        Template,
        TemplateDatabase,
        TemplateParams,
        build_database,
        build_object_templates,
        compute_fpfh,
        diameter,
        merge_equivalent_poses,
        resting_pose,
        sample_surface,
        template_from_cloud,
        yaw_period,
    )
