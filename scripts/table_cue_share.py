"""Per frame of one view: the share of the bare table (off every ground-truth visible mask)
that each colour cue marks before the depth veto, with the grey cue's background peak and
cut-off (L units), to see which frames' tables the colour cues mark and why.
docs/bench/smoothed-localiser.md.

    python scripts/table_cue_share.py SCENES VIEW
"""
from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core.localise import SegmentationParams
from tlessbot_ros.core.localise.colour import histogram_background_peak, remove_trend, rgb_to_lab
from tlessbot_ros.core.localise.cues import COLOUR_CUES, downscale
from tlessbot_ros.io.bop import read_split

sys.path.insert(0, str(Path(__file__).parent))
from table_false_parts_cues import truth_mask  # noqa: E402


def main(argv: list[str]) -> int:
    scenes, view = argv[:2]
    params = SegmentationParams()
    print('frame\t' + '\t'.join(f'{name} on table' for name, _ in COLOUR_CUES)
          + '\tgrey peak\tgrey cut-off')
    for image in read_split(scenes, f'test_{view}'):
        small = downscale(image.rgb, params.cue_scale)
        lab = rgb_to_lab(small)
        table = ~cv2.resize(truth_mask(image).view(np.uint8), small.shape[1::-1],
                            interpolation=cv2.INTER_NEAREST).astype(bool)
        shares = [cue(small, lab, None, params)[0][table].mean() for _, cue in COLOUR_CUES]
        peak, sigma = histogram_background_peak(remove_trend(lab[..., 0]),
                                                border_fraction=params.border_fraction)
        cutoff = max(params.cutoff_sigma * sigma, params.grey_floor)
        print(f'{image.im_id}\t' + '\t'.join(f'{s:.3f}' for s in shares)
              + f'\t{peak:.1f}\t{cutoff:.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
