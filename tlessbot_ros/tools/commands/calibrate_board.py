"""Measure the rig from a bag of a ChArUco board on the table (to become calibrate --board).

    tlessbot calibrate-board --bag BAG [--config config/cell.yaml] [--out cell_measured.yaml]

Every camera of the config's rig must see the board, lying still, in some of its colour images;
``--board-*`` describe the print (``tlessbot board`` prints one) and where it lies: by default
its centre is the world's origin, x along its rows, z up.
"""
from __future__ import annotations

import argparse

from tlessbot_ros.tools.support.board_calibration import (
    add_calibrate_arguments,
    run_board_calibration,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_calibrate_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return run_board_calibration(args)
