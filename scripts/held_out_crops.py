"""Top-1 of parts classifiers on the crops of held-out simulated scenes, by depth: per-pixel,
smoothed with the exact visible masks, and smoothed with the masks grown as the localiser's
regions are on it (``sim.noise.stereo_region``). docs/bench/smoothed-training-depth.md.

    python scripts/held_out_crops.py MODELS CLASSIFIER.npz... [--scenes 60] [--seed 424242]

MODELS: a parts folder's models/ (obj_NN files). Each crop is a part with at least 100 visible
pixels in either view; the classifiers must share their HOG and shape settings.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.tools.support.scene_crops import scene_features

# (label, share of smoothed scenes, pixels the smoothed masks grow)
DEPTHS = (('per-pixel', 0.0, 0), ('smoothed, exact masks', 1.0, 0),
          ("smoothed, masks as the localiser's", 1.0, 1))


def top1(model: LinearClassifier, features: np.ndarray, labels: np.ndarray) -> float:
    """Share of the crops ``model`` names right (no rejection); NaN shape values take the
    model's fill, as :meth:`LinearClassifier.describe` gives them."""
    features = features.copy()
    hog_dim = model.hog_params.feature_dim
    unusable = np.isnan(features[:, hog_dim])
    features[unusable, hog_dim:] = model.shape_fill
    return float(np.mean(model.predict(features, reject_margin=0.0).class_ids == labels))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('models', type=Path)
    ap.add_argument('classifiers', type=Path, nargs='+')
    ap.add_argument('--scenes', type=int, default=60)
    ap.add_argument('--seed', type=int, default=424242, help='simulator seed (held out)')
    args = ap.parse_args()
    models = [LinearClassifier.load(path) for path in args.classifiers]
    hog, shape = models[0].hog_params, models[0].shape_params
    print('depth | crops | ' + ' | '.join(str(path) for path in args.classifiers))
    for label, share, grow in DEPTHS:
        features, labels = scene_features(args.models, hog, shape, ids=None,
                                          scenes=args.scenes, seed=args.seed, workers=1,
                                          smoothed_share=share, region_px=grow)
        print(f'{label} | {len(labels)} | '
              + ' | '.join(f'{top1(m, features, labels):.3f}' for m in models), flush=True)


if __name__ == '__main__':
    main()
