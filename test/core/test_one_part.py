"""One part found as two instances is one part after the fit (issue 41, core/one_part.py):
the piece another part's fit explains joins that part, region and box."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import default_rig, mask_box
from tlessbot_ros.core.fragments import FragmentFilter
from tlessbot_ros.core.one_part import join_pieces
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput

SIDE = default_rig()['side']


@pytest.fixture(scope='module')
def halves(part21_seen_from_the_side):
    """Part 21 seen by the side camera, its region divided in two at its middle column (as
    the fusion divides it where the top camera sees two blobs)."""
    db, depth, mask, _ = part21_seen_from_the_side
    depth = depth + np.random.default_rng(3).normal(0, 0.0005, depth.shape).astype(
        np.float32) * (depth > 0)
    views = {'side': ViewInput(np.full((*depth.shape, 3), 90, np.uint8), depth,
                               SIDE.intrinsics, SIDE.T_world_camera)}
    labels = mask.astype(np.uint16)
    columns = np.nonzero(mask)[1]
    labels[:, int(np.median(columns)):] *= 2
    return db, views, {'side': labels}, mask


def test_a_part_divided_in_two_is_found_once_with_its_whole_region(halves):
    db, views, labels, mask = halves
    assert set(np.unique(labels['side'])) == {0, 1, 2}
    found = PerceptionPipeline(templates=db).estimate_poses(views, labels, {1: (21,), 2: (21,)})
    assert len(found) == 1 and found[0].obj_id == 21 and found[0].pose is not None
    kept = found[0].instance_id
    assert set(np.unique(labels['side'])) == {0, kept}          # the other region joined it
    assert np.array_equal(labels['side'] == kept, mask)
    assert found[0].box == mask_box(mask)


def test_two_parts_side_by_side_stay_two(part21_seen_from_the_side):
    """Two copies of part 21, 12 cm apart in the image's width: no fit explains the other."""
    db, depth, mask, _ = part21_seen_from_the_side
    shift = int(0.5 * mask.shape[1] - np.ptp(np.nonzero(mask)[1])) // 2 or 1
    two_depth, labels = depth.copy(), mask.astype(np.uint16)
    moved = np.roll(mask, shift, axis=1)
    assert not (moved & mask).any()
    two_depth[moved] = np.roll(depth, shift, axis=1)[moved]
    labels[moved] = 2
    views = {'side': ViewInput(np.full((*depth.shape, 3), 90, np.uint8), two_depth,
                               SIDE.intrinsics, SIDE.T_world_camera)}
    found = PerceptionPipeline(templates=db).estimate_poses(views, {'side': labels},
                                                            {1: (21,), 2: (21,)})
    assert sorted(d.instance_id for d in found) == [1, 2]


class _Detection:
    def __init__(self, instance_id, view='side'):
        self.instance_id, self.view, self.box = instance_id, view, (0, 0, 0, 0)


def test_the_explaining_fit_is_kept_whatever_the_scores_and_its_piece_joins_it():
    """Piece 2 fits better on its own points, but only 1's fit explains both: 2 joins 1."""
    a, b = _Detection(1), _Detection(2)
    published = []
    arbiter = FragmentFilter([(a, np.zeros(3), 'world', 400, 0.08),
                              (b, np.full(3, 0.03), 'world', 500, 0.08)], published.append,
                             overlap=0.5, explains=lambda x, y: x is a)
    arbiter.fitted(b, np.full(3, 0.03), 0.05, 0.99)
    arbiter.fitted(a, np.zeros(3), 0.08, 0.90)
    assert published == [a] and arbiter.dropped == [b]
    labels = {'side': np.array([[0, 1, 1, 2, 2]], np.uint16),
              'top': np.array([[2, 2, 0]], np.uint16)}
    before = labels['side']
    assert join_pieces(arbiter, [a, b], labels) == [a]
    assert labels['side'].tolist() == [[0, 1, 1, 1, 1]] and labels['top'].tolist() == [[1, 1, 0]]
    assert before.tolist() == [[0, 1, 1, 2, 2]]                  # replaced, not written into
    assert a.box == (1, 0, 4, 1)
