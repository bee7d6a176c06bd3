"""Stage 1, localisation: per-view segmentation (colour cues, depth, instance separation)
and the two-view fusion that gives one id per part in both views.

This package's public API; names load on first use, so importing one light module
(geometry, say) does not import Open3D."""
from __future__ import annotations

from typing import TYPE_CHECKING

from tlessbot_ros.lazy import lazy_api

# name -> the module of this package that defines it
_HOME = {
    'histogram_background_peak': 'colour',
    'remove_trend': 'colour',
    'rgb_to_hed': 'colour',
    'rgb_to_lab': 'colour',
    'BackgroundModel': 'cues',
    'hed_masks': 'cues',
    'height_above_table': 'cues',
    'lab_masks': 'cues',
    'prepare_background': 'cues',
    'boxes_from_labels': 'instances',
    'relabel_sequential': 'instances',
    'split_touching': 'instances',
    'watershed_refine': 'instances',
    'METHODS': 'params',
    'SegmentationParams': 'params',
    'Segmentation': 'segmentation',
    'segment': 'segmentation',
    'longest_part_px': 'part_scale',
    'part_view_areas': 'part_scale',
    'part_view_size': 'part_scale',
    'view_segmentation': 'part_scale',
    'robust_quadratic_fit': 'surface_fit',
    'FUSION_METHODS': 'fusion_result',
    'FusedInstance': 'fusion_result',
    'FusionParams': 'fusion_result',
    'FusionResult': 'fusion_result',
    'fuse_views': 'two_view',
    'lift_top_blobs': 'calibrated_fusion',
    'predict_side_regions': 'calibrated_fusion',
    'single_view': 'two_view',
    'table_homography': 'part_length',
}
__all__ = sorted(_HOME)

__getattr__, __dir__ = lazy_api(__name__, _HOME)

if TYPE_CHECKING:
    from tlessbot_ros.core.localise.calibrated_fusion import (  # noqa: F401
        lift_top_blobs,
        predict_side_regions,
    )
    from tlessbot_ros.core.localise.colour import (  # noqa: F401
        histogram_background_peak,
        remove_trend,
        rgb_to_hed,
        rgb_to_lab,
    )
    from tlessbot_ros.core.localise.cues import (  # noqa: F401
        BackgroundModel,
        hed_masks,
        height_above_table,
        lab_masks,
        prepare_background,
    )
    from tlessbot_ros.core.localise.fusion_result import (  # noqa: F401
        FUSION_METHODS,
        FusedInstance,
        FusionParams,
        FusionResult,
    )
    from tlessbot_ros.core.localise.instances import (  # noqa: F401
        boxes_from_labels,
        relabel_sequential,
        split_touching,
        watershed_refine,
    )
    from tlessbot_ros.core.localise.params import (  # noqa: F401
        METHODS,
        SegmentationParams,
    )
    from tlessbot_ros.core.localise.part_length import table_homography  # noqa: F401
    from tlessbot_ros.core.localise.part_scale import (  # noqa: F401
        longest_part_px,
        part_view_areas,
        part_view_size,
        view_segmentation,
    )
    from tlessbot_ros.core.localise.segmentation import (  # noqa: F401
        Segmentation,
        segment,
    )
    from tlessbot_ros.core.localise.surface_fit import (  # noqa: F401
        robust_quadratic_fit,
    )
    from tlessbot_ros.core.localise.two_view import (  # noqa: F401
        fuse_views,
        single_view,
    )
