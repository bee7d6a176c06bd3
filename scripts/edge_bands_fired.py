"""Where the edge-band rule fires: ``tlessbot evaluate`` with a line for each band it drops.
docs/bench/smoothed-false-parts-now.md section 7.

    python scripts/edge_bands_fired.py EVALUATE ARGUMENTS...

Prints ``BAND <caller> <piece> <anchor> <piece px> <anchor px>`` each time
``core.edge_bands.is_edge_band`` answers yes (``split_off``: the division after the fit;
``band``: the fragment filter), between `evaluate`'s progress lines.
"""
from __future__ import annotations

import sys
import traceback

import tlessbot_ros.core.edge_bands as edge_bands
import tlessbot_ros.core.two_parts as two_parts

_original = edge_bands.is_edge_band


def _spy(image, piece, anchor, band_px):
    answer = _original(image, piece, anchor, band_px)
    if answer:
        caller = traceback.extract_stack()[-2].name
        print('BAND', caller, piece, anchor, int((image == piece).sum()),
              int((image == anchor).sum()), flush=True)
    return answer


if __name__ == '__main__':
    edge_bands.is_edge_band = _spy
    two_parts.is_edge_band = _spy
    from tlessbot_ros.tools.cli import main
    sys.exit(main(['evaluate', *sys.argv[1:]]) or 0)
