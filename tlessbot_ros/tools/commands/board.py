"""Write a printable ChArUco board for tlessbot calibrate --board (PNG at a given DPI).

    tlessbot board --out board.png [--dpi 300] [--board-squares 7 5 --board-square-m 0.055]

Print it at 100 % ("actual size"; the default board fits A3), lay it flat on the table where
both cameras see it, measure a square and pass that length as ``--board-square-m`` (and the
marker's as ``--board-marker-m``) if the printer scaled it.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.tools.support.board_calibration import add_board_arguments, board_from_args

INCH_M = 0.0254


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out', type=Path, required=True, help='PNG file to write')
    parser.add_argument('--dpi', type=float, default=300.0, help='print resolution (default 300)')
    parser.add_argument('--margin-m', type=float, default=0.01,
                        help='white margin around the squares, metres (default 0.01)')
    add_board_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from matplotlib import image as mpimg

    if args.dpi <= 0 or args.margin_m < 0:
        raise TlessbotError('--dpi must be positive and --margin-m at least 0')
    board = board_from_args(args)
    px_per_m = args.dpi / INCH_M
    picture = board.image(px_per_m, margin_px=int(round(args.margin_m * px_per_m)))
    try:
        mpimg.imsave(args.out, picture, cmap='gray', vmin=0, vmax=255, dpi=args.dpi,
                     format='png')
    except OSError as error:
        raise TlessbotError(f'cannot write {args.out}: {error}') from None
    width, height = (1000.0 * s / px_per_m for s in picture.shape[::-1])
    print(f'wrote {args.out}: {board.squares_x} x {board.squares_y} squares of '
          f'{1000 * board.square_length_m:g} mm, markers {1000 * board.marker_length_m:g} mm '
          f'({board.dictionary}); {width:.0f} x {height:.0f} mm at {args.dpi:g} dpi')
    return 0
