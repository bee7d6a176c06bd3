"""The causes ``tlessbot evaluate`` gives its misses and false positives (eval_breakdown)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from tlessbot_ros.core.common import mask_box
from tlessbot_ros.tools.support.eval_breakdown import add_up, confusions, frame_breakdown
from tlessbot_ros.tools.support.eval_scoring import _match_boxes


def _gt(obj_id: int, mask: np.ndarray, visib: float = 1.0):
    return SimpleNamespace(obj_id=obj_id, mask=mask, visib_fract=visib,
                           bbox_visib=mask_box(mask))


def _rect(y0, y1, x0, x1, shape=(120, 160)):
    mask = np.zeros(shape, bool)
    mask[y0:y1, x0:x1] = True
    return mask


def _scored(gts, labels, classes):
    image = SimpleNamespace(gt=gts, depth_m=None, T_world_camera=None)
    ids = [i for i in np.unique(labels) if i]
    boxes = [(*mask_box(labels == i), classes.get(int(i), 0)) for i in ids]
    matched, _ = _match_boxes(image, boxes)
    return image, boxes, matched


def test_each_cause_is_named():
    found, split = _rect(10, 30, 10, 40), _rect(10, 30, 60, 100)
    left, right = _rect(60, 80, 10, 40), _rect(60, 80, 40, 70)   # touching: one blob
    lost = _rect(100, 110, 120, 130)
    gts = [_gt(1, found), _gt(2, split), _gt(3, left), _gt(4, right), _gt(5, lost)]
    labels = np.zeros(found.shape, np.uint16)
    labels[found] = 1
    labels[_rect(10, 30, 60, 80)] = 2           # two halves of part 2
    labels[_rect(10, 30, 80, 100)] = 3
    labels[left | right] = 4                    # parts 3 and 4 as one
    labels[_rect(95, 100, 140, 155)] = 5        # on the table
    image, boxes, matched = _scored(gts, labels, {1: 1, 2: 2, 3: 2, 4: 3})
    out = frame_breakdown(image, labels, boxes, matched)
    assert out['missed'] == {'not found': 1, 'merged': 2, 'split': 1, 'box off': 0}
    assert out['missed_by_obj'][5]['not found'] == 1
    assert out['false_pos']['piece of a missed part'] == 2
    assert out['false_pos']['merged'] == 1
    assert out['false_pos']['table, flat'] == 1
    assert out['false_pos_posed']['table, flat'] == 0   # no pose was published for it
    total = add_up([out, out])
    assert total['missed']['merged'] == 4 and total['missed_by_obj']['5']['not found'] == 2


def test_a_piece_of_a_found_part_and_a_wrong_name():
    part = _rect(10, 50, 10, 50)
    labels = np.zeros(part.shape, np.uint16)
    labels[part] = 1
    labels[_rect(40, 52, 40, 52)] = 2           # a fragment on the part's corner
    image, boxes, matched = _scored([_gt(7, part)], labels, {1: 8, 2: 7})
    out = frame_breakdown(image, labels, boxes, matched)
    assert sum(out['missed'].values()) == 0
    assert out['false_pos']['piece of a found part'] == 1
    assert confusions([(image, boxes, matched)]) == {'7 -> 8': 1}


def test_loss_tables_name_the_parts():
    """report.md's loss tables and the 'named as another part' line carry the parts' names
    (obj_NN for a part the names do not list; 0: no pose)."""
    from tlessbot_ros.tools.support.eval_breakdown import markdown

    part = _rect(10, 50, 10, 50)
    image, boxes, matched = _scored([_gt(7, part)], np.zeros(part.shape, np.uint16), {})
    total = add_up([frame_breakdown(image, np.zeros(part.shape, np.uint16), boxes, matched)])
    total['confusions'] = {'7 -> 8': 2, '7 -> 0': 1, '8 -> 7': 1}
    text = '\n'.join(markdown(total, 1, {7: 'bracket_l', 9: 'plate'}))
    assert '| bracket_l | ' in text and 'obj_07' not in text
    assert 'bracket_l -> obj_08 (2), bracket_l -> 0 (1), obj_08 -> bracket_l (1).' in text
