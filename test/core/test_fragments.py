"""One part, one pose (core/fragments.py): fragments dropped whatever the completion order."""
from itertools import permutations

import numpy as np

from tlessbot_ros.core.fragments import FragmentFilter


class _Detection:
    def __init__(self, instance_id):
        self.instance_id = instance_id


def _run(order, overlap=0.5):
    """Four pieces: 1 and 2 are halves of one part (centres 1 cm apart after the fit, 2 fits
    better), 3 touches them but is another part (centre 6 cm away), 4 lies far away; 5 has no
    pose."""
    d = {i: _Detection(i) for i in range(1, 6)}
    rois = {1: [0.0, 0.0, 0.02], 2: [0.02, 0.0, 0.02], 3: [0.07, 0.0, 0.02],
            4: [0.5, 0.5, 0.02], 5: [0.03, 0.01, 0.02]}
    points = {1: 900, 2: 500, 3: 800, 4: 700, 5: 100}
    fits = {1: ([0.010, 0.0, 0.02], 0.92), 2: ([0.012, 0.008, 0.02], 0.98),
            3: ([0.07, 0.0, 0.02], 0.95), 4: ([0.5, 0.5, 0.02], 0.9), 5: (None, 0.0)}
    published = []
    arbiter = FragmentFilter([(d[i], np.array(rois[i]), 'world', points[i], 0.08)
                              for i in d], published.append, overlap=overlap)
    for i in order:
        centre, fitness = fits[i]
        arbiter.fitted(d[i], None if centre is None else np.array(centre), 0.08, fitness)
    return sorted(x.instance_id for x in published), sorted(x.instance_id for x in
                                                            arbiter.dropped)


def test_the_worse_fit_of_one_part_is_dropped_in_every_completion_order():
    results = {_run(order) == ([2, 3, 4, 5], [1]) for order in permutations(range(1, 6))}
    assert results == {True}


def test_a_lone_part_goes_out_as_soon_as_it_is_fitted():
    d = _Detection(7)
    published = []
    arbiter = FragmentFilter([(d, np.zeros(3), 'world', 500, 0.08),
                              (_Detection(8), np.ones(3), 'world', 900, 0.08)],
                             published.append, overlap=0.5)
    arbiter.fitted(d, np.zeros(3), 0.08, 0.9)
    assert published == [d]          # its only other piece is far away: nothing to wait for


def test_no_check_keeps_every_piece():
    assert _run(range(1, 6), overlap=0.0) == ([1, 2, 3, 4, 5], [])


def test_pieces_in_different_camera_frames_are_never_compared():
    a, b = _Detection(1), _Detection(2)
    published = []
    arbiter = FragmentFilter([(a, np.zeros(3), 'top', 900, 0.08),
                              (b, np.zeros(3), 'side', 500, 0.08)], published.append,
                             overlap=0.5)
    arbiter.fitted(b, np.zeros(3), 0.08, 0.9)
    arbiter.fitted(a, np.zeros(3), 0.08, 0.99)
    assert published == [b, a] and arbiter.dropped == []


def test_ground_truth_boxes_are_never_fragments():
    """Two long parts whose boxes overlap in a pile, fitted 3 cm apart: with the filter on the
    worse is taken for a fragment; in box mode (overlap 0) both go out."""
    from types import SimpleNamespace

    from tlessbot_ros.core.fragments import fragment_filter

    database = {5: SimpleNamespace(diameter_m=0.17)}
    for overlap, kept in ((0.5, [1]), (0.0, [1, 2])):
        jobs = [SimpleNamespace(detection=_Detection(i), points=np.full((50, 3), 0.03 * i),
                                T_world_camera=None, candidates=(5,)) for i in (1, 2)]
        for job in jobs:
            job.detection.view = 'side'
        published = []
        arbiter = fragment_filter(jobs, published.append, database, overlap)
        for job, fitness in zip(jobs, (0.9, 0.8)):
            arbiter.fitted(job.detection, job.points[0].copy(), 0.17, fitness)
        assert sorted(d.instance_id for d in published) == kept
