"""pair_roots: items grouped by pairs, transitively (the fusion's and the gap rule's groups)."""
from tlessbot_ros.core.localise.blob_split import pair_roots


def test_pairs_join_transitively_and_apart_items_keep_their_own_root():
    joined = {(0, 2), (2, 3)}
    roots = pair_roots(5, lambda a, b: (a, b) in joined)
    assert roots[0] == roots[2] == roots[3]
    assert len({roots[0], roots[1], roots[4]}) == 3
    assert sorted(set(roots)) == sorted({roots[0], 1, 4})


def test_no_pair_together_leaves_every_item_alone_and_each_pair_is_asked_once():
    asked = []
    roots = pair_roots(4, lambda a, b: asked.append((a, b)) or False)
    assert roots == [0, 1, 2, 3]
    assert asked == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
