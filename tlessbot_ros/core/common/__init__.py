"""Pieces every stage shares: camera geometry, the rig, label images, frame pairing,
mesh rendering, surface sampling and symmetries. Imports no stage.

This package's public API; names load on first use, so importing one light module
(geometry, say) does not import Open3D."""
from __future__ import annotations

from typing import TYPE_CHECKING

from tlessbot_ros.lazy import lazy_api

# name -> the module of this package that defines it
_HOME = {
    'AdmissionParams': 'admission',
    'InFlightFrames': 'admission',
    'table_with_box': 'warm_frame',
    'CameraIntrinsics': 'geometry',
    'RegionOfInterest': 'geometry',
    'depth_to_points': 'geometry',
    'invert_transform': 'geometry',
    'look_at': 'geometry',
    'make_transform': 'geometry',
    'mask_box': 'geometry',
    'matrix_from_quaternion': 'geometry',
    'point_set_diameter': 'geometry',
    'project_points': 'geometry',
    'quaternion_from_matrix': 'geometry',
    'nearest_rotation': 'geometry',
    'rotation_about_axis': 'geometry',
    'rotation_angle_deg': 'geometry',
    'rpy_from_matrix': 'geometry',
    'transform_points': 'geometry',
    'CLASS_STRIDE': 'labels',
    'MAX_INSTANCES': 'labels',
    'decode_candidates': 'labels',
    'decode_classes': 'labels',
    'encode_candidates': 'labels',
    'encode_classes': 'labels',
    'instance_masks': 'labels',
    'label_boxes': 'labels',
    'pixel_counts': 'labels',
    'check_part_name': 'names',
    'check_part_names': 'names',
    'default_part_name': 'names',
    'part_id': 'names',
    'part_name': 'names',
    'suggest_part_name': 'names',
    'OverlayPart': 'overlay',
    'centre_of_mass': 'resting',
    'resting_poses': 'resting',
    'depth_overlay': 'overlay',
    'MeshRenderer': 'render',
    'NO_HIT': 'render',
    'RenderResult': 'render',
    'o3d_tensor': 'render',
    'raycasting_scene': 'render',
    'CAMERA_NAMES': 'rig',
    'SIDE': 'rig',
    'TOP': 'rig',
    'CameraMount': 'rig',
    'D415_FOCAL_PX_AT_640': 'rig',
    'Rig': 'rig',
    'check_camera_roles': 'rig',
    'd415_intrinsics': 'rig',
    'default_rig': 'rig',
    'look_at_params': 'rig',
    'rig_from_params': 'rig',
    'side_camera_position': 'rig',
    'SAMPLING_SCHEMES': 'sampling',
    'sample_surface': 'sampling',
    'Symmetries': 'symmetry',
    'SymmetryParams': 'symmetry_detect',
    'detect_symmetries': 'symmetry_detect',
    'symmetries_from_models_info': 'symmetry',
    'symmetries_to_models_info': 'symmetry',
    'TABLE_PLANE_MODES': 'table_plane',
    'TableFrame': 'table_plane',
    'TablePlane': 'table_plane',
    'TablePlaneParams': 'table_plane',
    'TablePlaneTracker': 'table_plane',
    'align_frame_to_plane': 'table_plane',
    'choose_table_frame': 'table_plane',
    'find_table_plane': 'table_plane',
    'plane_difference': 'table_plane',
    'plane_of_frame': 'table_plane',
    'table_frame_from_plane': 'table_plane',
    'above_table': 'table_plane',
    'Item': 'sync',
    'JUMP': 'timeline',
    'STALE': 'timeline',
    'StampJumps': 'timeline',
    'StampSynchroniser': 'sync',
    'TimelineGate': 'timeline',
    'SyncParams': 'sync',
    'SkippedFrames': 'sync',
    'stream_period_ns': 'sync',
}
__all__ = sorted(_HOME)

__getattr__, __dir__ = lazy_api(__name__, _HOME)

if TYPE_CHECKING:
    from tlessbot_ros.core.common.admission import AdmissionParams, InFlightFrames  # noqa: F401
    from tlessbot_ros.core.common.geometry import (  # noqa: F401
        CameraIntrinsics,
        RegionOfInterest,
        depth_to_points,
        invert_transform,
        look_at,
        make_transform,
        mask_box,
        matrix_from_quaternion,
        nearest_rotation,
        point_set_diameter,
        project_points,
        quaternion_from_matrix,
        rotation_about_axis,
        rotation_angle_deg,
        rpy_from_matrix,
        transform_points,
    )
    from tlessbot_ros.core.common.labels import (  # noqa: F401
        CLASS_STRIDE,
        MAX_INSTANCES,
        decode_candidates,
        decode_classes,
        encode_candidates,
        encode_classes,
        instance_masks,
        label_boxes,
        pixel_counts,
    )
    from tlessbot_ros.core.common.names import (  # noqa: F401
        check_part_name,
        check_part_names,
        default_part_name,
        part_id,
        part_name,
        suggest_part_name,
    )
    from tlessbot_ros.core.common.overlay import OverlayPart, depth_overlay  # noqa: F401
    from tlessbot_ros.core.common.render import (  # noqa: F401
        NO_HIT,
        MeshRenderer,
        RenderResult,
        o3d_tensor,
        raycasting_scene,
    )
    from tlessbot_ros.core.common.resting import centre_of_mass, resting_poses  # noqa: F401
    from tlessbot_ros.core.common.rig import (  # noqa: F401
        CAMERA_NAMES,
        D415_FOCAL_PX_AT_640,
        SIDE,
        TOP,
        CameraMount,
        Rig,
        check_camera_roles,
        d415_intrinsics,
        default_rig,
        look_at_params,
        rig_from_params,
        side_camera_position,
    )
    from tlessbot_ros.core.common.sampling import (  # noqa: F401
        SAMPLING_SCHEMES,
        sample_surface,
    )
    from tlessbot_ros.core.common.symmetry import (  # noqa: F401
        Symmetries,
        symmetries_from_models_info,
        symmetries_to_models_info,
    )
    from tlessbot_ros.core.common.symmetry_detect import (  # noqa: F401
        SymmetryParams,
        detect_symmetries,
    )
    from tlessbot_ros.core.common.sync import (  # noqa: F401
        Item,
        SkippedFrames,
        StampSynchroniser,
        SyncParams,
        stream_period_ns,
    )
    from tlessbot_ros.core.common.table_plane import (  # noqa: F401
        TABLE_PLANE_MODES,
        TableFrame,
        TablePlane,
        TablePlaneParams,
        TablePlaneTracker,
        above_table,
        align_frame_to_plane,
        choose_table_frame,
        find_table_plane,
        plane_difference,
        plane_of_frame,
        table_frame_from_plane,
    )
    from tlessbot_ros.core.common.timeline import (  # noqa: F401
        JUMP,
        STALE,
        StampJumps,
        TimelineGate,
    )
    from tlessbot_ros.core.common.warm_frame import table_with_box  # noqa: F401
