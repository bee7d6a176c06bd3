"""Camera calibration of the cell: the rig estimated from the scene the cameras see
(``scene``: the calibrator, ``observation``: what a frame gives it, ``inplane`` and
``inplane_fit``: the in-plane geometry and fit, ``params``, ``comparison``: how far two rigs
are apart), and what a running localiser does with it (``refinement``); or measured once with a
printed ChArUco board (``board``: the board and its detection, ``board_pose``: the pose one
image gives, ``board_rig``: intrinsics and the rig).

This package's public API; names load on first use, so importing it does not import OpenCV or
the perception pipeline."""
from __future__ import annotations

from typing import TYPE_CHECKING

from tlessbot_ros.lazy import lazy_api

# name -> the module of this package that defines it
_HOME = {
    'CALIBRATION_PLANE': 'params',
    'SceneCalibrationParams': 'params',
    'FrameObservation': 'observation',
    'ViewObservation': 'observation',
    'observe_view': 'observation',
    'view_stride_px': 'observation',
    'RigDifference': 'comparison',
    'RigErrors': 'comparison',
    'pose_difference': 'comparison',
    'rig_differences': 'comparison',
    'rig_errors': 'comparison',
    'RigEstimate': 'scene',
    'SceneCalibrator': 'scene',
    'inplane_parameters': 'inplane',
    'inplane_transform': 'inplane',
    'level_camera_on_plane': 'inplane',
    'procrustes_2d': 'inplane',
    'BoardDetection': 'board',
    'BoardSpec': 'board',
    'board_on_table': 'board',
    'detect_board': 'board',
    'BoardPose': 'board_pose',
    'board_pose': 'board_pose',
    'camera_pose_from_board': 'board_pose',
    'fit_board_pose': 'board_pose',
    'CameraCalibration': 'board_rig',
    'calibrate_camera': 'board_rig',
    'calibrate_rig': 'board_rig',
    'RIG_REFINEMENT_MODES': 'refinement',
    'RefinementStatus': 'refinement',
    'RigRefinementParams': 'refinement',
    'RigRefiner': 'refinement',
    'refined_pipeline': 'refinement',
}
__all__ = sorted(_HOME)

__getattr__, __dir__ = lazy_api(__name__, _HOME)

if TYPE_CHECKING:
    from tlessbot_ros.core.calibrate.board import (  # noqa: F401
        BoardDetection,
        BoardSpec,
        board_on_table,
        detect_board,
    )
    from tlessbot_ros.core.calibrate.board_pose import (  # noqa: F401
        BoardPose,
        board_pose,
        camera_pose_from_board,
        fit_board_pose,
    )
    from tlessbot_ros.core.calibrate.board_rig import (  # noqa: F401
        CameraCalibration,
        calibrate_camera,
        calibrate_rig,
    )
    from tlessbot_ros.core.calibrate.comparison import (  # noqa: F401
        RigDifference,
        RigErrors,
        pose_difference,
        rig_differences,
        rig_errors,
    )
    from tlessbot_ros.core.calibrate.inplane import (  # noqa: F401
        inplane_parameters,
        inplane_transform,
        level_camera_on_plane,
        procrustes_2d,
    )
    from tlessbot_ros.core.calibrate.observation import (  # noqa: F401
        FrameObservation,
        ViewObservation,
        observe_view,
        view_stride_px,
    )
    from tlessbot_ros.core.calibrate.params import (  # noqa: F401
        CALIBRATION_PLANE,
        SceneCalibrationParams,
    )
    from tlessbot_ros.core.calibrate.refinement import (  # noqa: F401
        RIG_REFINEMENT_MODES,
        RefinementStatus,
        RigRefinementParams,
        RigRefiner,
        refined_pipeline,
    )
    from tlessbot_ros.core.calibrate.scene import (  # noqa: F401
        RigEstimate,
        SceneCalibrator,
    )
