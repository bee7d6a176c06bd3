"""Stage 3, pose: region clouds, the template database, the table-plane and RANSAC pose
searches with their refinement, and the look-alike check.

Modules: ``cloud`` (ROI clouds, normals, FPFH), ``database`` (what the templates store, the
file format), ``building`` (rendering and building the templates), ``params`` and
``candidates`` (the settings and results of the pose search), ``estimator`` (the table-plane
search and the orchestration), ``hypotheses`` (the table path's resting hypotheses),
``refinement`` (ICP, planar Gauss-Newton, scoring: swap it with ``PoseEstimator(refiner=...)``),
``image_box`` (box mode: how much of a part's given box a pose covers),
``ransac`` (the paper's FPFH + RANSAC path), ``grid_kernels``
and ``buckets`` (the fast lookups), ``fallback`` (the bounded 6-DOF search for parts off the
table path), ``lookalike``, ``flat`` (which face of a flat part is up), ``turns`` (near-symmetric
turns told apart by the colour image), ``half_turns`` (half turns decided by every view's
height and colour), ``observability`` (what the rig can see of a turn), ``resting`` (a fit
on the table levelled onto a stable pose), ``derived``
(start-up arrays to cache).
Surface sampling is :func:`tlessbot_ros.core.common.sample_surface`.

This package's public API; names load on first use, so importing one light module
(geometry, say) does not import Open3D."""
from __future__ import annotations

from typing import TYPE_CHECKING

from tlessbot_ros.lazy import lazy_api

# name -> the module of this package that defines it
_HOME = {
    'DERIVED_VERSION': 'derived',
    'derived_arrays': 'derived',
    'restore_derived': 'derived',
    'PointBuckets': 'buckets',
    'TemplateParams': 'building',
    'build_database': 'building',
    'build_object_templates': 'building',
    'diameter': 'building',
    'merge_equivalent_poses': 'building',
    'resting_pose': 'building',
    'template_from_cloud': 'building',
    'yaw_period': 'building',
    'listed_yaw_period': 'building',
    'COVERAGE_WEIGHT': 'candidates',
    'PoseCandidate': 'candidates',
    'poses_differ': 'candidates',
    'PoseResult': 'candidates',
    'CloudParams': 'cloud',
    'compute_fpfh': 'cloud',
    'crop_box': 'cloud',
    'drop_steep': 'cloud',
    'estimate_normals': 'cloud',
    'fit_plane': 'cloud',
    'preprocess_roi': 'cloud',
    'remove_statistical_outliers': 'cloud',
    'rgbd_to_cloud': 'cloud',
    'roi_cloud': 'cloud',
    'steep_pixels': 'cloud',
    'subtract_background': 'cloud',
    'to_o3d': 'cloud',
    'voxel_downsample': 'cloud',
    'CONTINUOUS_YAW_PERIOD': 'database',
    'FORMAT': 'database',
    'NORMAL_SCALE': 'database',
    'NearestGrid': 'database',
    'ObjectTemplates': 'database',
    'POINT_QUANTUM_M': 'database',
    'READABLE_VERSIONS': 'database',
    'Template': 'database',
    'TemplateDatabase': 'database',
    'VERSION': 'database',
    'NearSymmetries': 'fallback',
    'ViewGrid': 'fallback',
    'fallback_candidates': 'fallback',
    'fibonacci_sphere': 'fallback',
    'near_symmetries': 'fallback',
    'rotation_between': 'fallback',
    'view_grid': 'fallback',
    'PoseEstimator': 'estimator',
    'table_frame_from_plane': 'estimator',
    'gauss_newton': 'grid_kernels',
    'inlier_fraction': 'grid_kernels',
    'normal_equations': 'grid_kernels',
    'self_visible': 'grid_kernels',
    'truncated_cost': 'grid_kernels',
    'ImageBox': 'image_box',
    'box_cover': 'image_box',
    'FlatCheck': 'flat',
    'FlatParams': 'flat_params',
    'ViewEvidence': 'flat_params',
    'is_flat_mesh': 'flat_params',
    'LookalikeCheck': 'lookalike',
    'MISS_ERROR_M': 'lookalike',
    'Mesh': 'lookalike',
    'depth_errors': 'lookalike',
    'clear_margin': 'lookalike',
    'depth_vote': 'lookalike',
    'lookalike_pairs': 'lookalike',
    'shared_surface': 'lookalike',
    'visible_difference': 'lookalike',
    'vote_counts': 'lookalike',
    'FALLBACK_METHODS': 'params',
    'METHODS': 'params',
    'PoseParams': 'params',
    'ransac_candidates': 'ransac',
    'register_templates': 'ransac',
    'Refiner': 'refinement',
    'inside_outline': 'silhouette',
    'TurnParams': 'turns',
    'RestingParams': 'resting',
    'settle': 'resting',
    'stable_directions': 'resting',
    'choose_half_turn': 'half_turns',
    'self_half_turns': 'half_turns',
    'choose_turn': 'turns',
    'near_turns': 'turns',
    'rendered_edges': 'turns',
    'AxisVisibility': 'observability',
    'ObservabilityParams': 'observability',
    'ViewOfTable': 'observability',
    'changed_pixels': 'observability',
    'turn_visibility': 'observability',
}
__all__ = sorted(_HOME)

__getattr__, __dir__ = lazy_api(__name__, _HOME)

if TYPE_CHECKING:
    from tlessbot_ros.core.common.table_plane import table_frame_from_plane  # noqa: F401
    from tlessbot_ros.core.pose.buckets import (  # noqa: F401
        PointBuckets,
    )
    from tlessbot_ros.core.pose.building import (  # noqa: F401
        TemplateParams,
        build_database,
        build_object_templates,
        diameter,
        listed_yaw_period,
        merge_equivalent_poses,
        resting_pose,
        template_from_cloud,
        yaw_period,
    )
    from tlessbot_ros.core.pose.candidates import (  # noqa: F401
        COVERAGE_WEIGHT,
        PoseCandidate,
        PoseResult,
        poses_differ,
    )
    from tlessbot_ros.core.pose.cloud import (  # noqa: F401
        CloudParams,
        compute_fpfh,
        crop_box,
        drop_steep,
        estimate_normals,
        fit_plane,
        preprocess_roi,
        remove_statistical_outliers,
        rgbd_to_cloud,
        roi_cloud,
        steep_pixels,
        subtract_background,
        to_o3d,
        voxel_downsample,
    )
    from tlessbot_ros.core.pose.database import (  # noqa: F401
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
    )
    from tlessbot_ros.core.pose.derived import (  # noqa: F401
        DERIVED_VERSION,
        derived_arrays,
        restore_derived,
    )
    from tlessbot_ros.core.pose.estimator import PoseEstimator  # noqa: F401
    from tlessbot_ros.core.pose.fallback import (  # noqa: F401
        NearSymmetries,
        ViewGrid,
        fallback_candidates,
        fibonacci_sphere,
        near_symmetries,
        rotation_between,
        view_grid,
    )
    from tlessbot_ros.core.pose.flat import FlatCheck  # noqa: F401
    from tlessbot_ros.core.pose.flat_params import (  # noqa: F401
        FlatParams,
        ViewEvidence,
        is_flat_mesh,
    )
    from tlessbot_ros.core.pose.grid_kernels import (  # noqa: F401
        gauss_newton,
        inlier_fraction,
        normal_equations,
        self_visible,
        truncated_cost,
    )
    from tlessbot_ros.core.pose.half_turns import (  # noqa: F401
        choose_half_turn,
        self_half_turns,
    )
    from tlessbot_ros.core.pose.image_box import ImageBox, box_cover  # noqa: F401
    from tlessbot_ros.core.pose.lookalike import (  # noqa: F401
        MISS_ERROR_M,
        LookalikeCheck,
        Mesh,
        clear_margin,
        depth_errors,
        depth_vote,
        lookalike_pairs,
        shared_surface,
        visible_difference,
        vote_counts,
    )
    from tlessbot_ros.core.pose.observability import (  # noqa: F401
        AxisVisibility,
        ObservabilityParams,
        ViewOfTable,
        changed_pixels,
        turn_visibility,
    )
    from tlessbot_ros.core.pose.params import (  # noqa: F401
        FALLBACK_METHODS,
        METHODS,
        PoseParams,
    )
    from tlessbot_ros.core.pose.ransac import (  # noqa: F401
        ransac_candidates,
        register_templates,
    )
    from tlessbot_ros.core.pose.refinement import (  # noqa: F401
        Refiner,
    )
    from tlessbot_ros.core.pose.resting import RestingParams, settle, stable_directions  # noqa: F401
    from tlessbot_ros.core.pose.silhouette import inside_outline  # noqa: F401
    from tlessbot_ros.core.pose.turns import (  # noqa: F401
        TurnParams,
        choose_turn,
        near_turns,
        rendered_edges,
    )
