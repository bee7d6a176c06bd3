"""tlessbot parts generate --seed: held-out parts drawn from a seed, the same for the same seed,
closed, validly named, with the symmetries they list and their look-alike pairs."""
import json

import numpy as np
import pytest

from tlessbot_ros.core.common.names import check_part_names
from tlessbot_ros.io.parts import cad_parts, read_part_mesh
from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.support import part_family
from tlessbot_ros.tools.support.part_family import (
    DISTINCT_MM,
    FLAT_KINDS,
    box_turns,
    family,
    largest_change,
    shape,
)


def test_a_seed_draws_the_same_family_and_another_seed_another():
    first = family(7, 8)
    assert family(7, 8) == first
    assert json.loads(json.dumps(first)) == first           # plain numbers: family.json
    other = family(8, 8)
    assert [s for s in other.values()] != [s for s in first.values()]
    three = list(family(7, 3))
    assert len(three) == 3 and three[:2] == ['plate_7a', 'plate_7b']
    check_part_names(dict(enumerate(first, 1)))
    check_part_names(dict(enumerate(family(123, 26), 1)))
    with pytest.raises(ValueError, match='count'):
        family(7, 0)


@pytest.mark.parametrize('seed', [7, 8, 11])
def test_every_kind_and_the_look_alike_pairs_are_drawn(seed):
    parts = family(seed, 8)
    assert {s['kind'] for s in parts.values()} == set(part_family.KINDS)
    twins = [(n, s) for n, s in parts.items() if 'twin_of' in s]
    mirrors = [(n, s) for n, s in parts.items() if 'mirror_of' in s]
    assert len(twins) == 1 and len(mirrors) == 1
    name, twin = twins[0]
    plate = parts[twin['twin_of']]
    assert len(twin['cuts']) == len(plate['cuts']) - 1
    assert all(c in plate['cuts'] for c in twin['cuts'])
    assert {k: v for k, v in twin.items() if k not in ('cuts', 'twin_of')} == {
        k: v for k, v in plate.items() if k != 'cuts'}
    name, mirror = mirrors[0]
    original = parts[mirror['mirror_of']]
    (sdf_m, bounds), (sdf_o, _) = shape(mirror), shape(original)
    reflect = np.diag([1.0, -1.0, 1.0, 1.0])
    assert largest_change(sdf_m, sdf_o, bounds, reflect) < 1e-9     # its mirror image
    assert largest_change(sdf_m, sdf_o, bounds) > DISTINCT_MM       # and another part
    for spec in parts.values():
        if spec['kind'] in FLAT_KINDS:
            assert 3.0 <= spec['thickness'] <= 6.0


@pytest.mark.parametrize('seed', [7, 8])
def test_the_parts_have_exactly_the_symmetries_they_list(seed):
    for name, spec in family(seed, 8).items():
        sdf, bounds = shape(spec)
        listed = part_family.symmetries(spec)['symmetries_discrete']
        for T in listed:
            assert largest_change(sdf, sdf, bounds, np.reshape(T, (4, 4))) < 0.05, name
        if spec['kind'] not in ('disc', 'tube'):
            assert not listed
            assert all(largest_change(sdf, sdf, bounds, T, step_mm=1.0) > DISTINCT_MM
                       for T in box_turns(spec)), name


def test_generate_with_a_seed_writes_closed_parts_the_build_accepts(tmp_path, capsys):
    out = tmp_path / 'cad'
    assert main(['parts', 'generate', '--out', str(out), '--seed', '5', '--count', '8']) == 0
    assert '8 parts' in capsys.readouterr().out
    specs = family(5, 8)
    parts = cad_parts(out)
    assert sorted(p.name for p in parts) == sorted(specs)
    for part in parts:
        vertices, faces, warnings = read_part_mesh(part.path)
        assert warnings == [], part.name                         # closed, nothing to warn of
        low, high = shape(specs[part.name])[1]
        assert np.ptp(vertices, axis=0) * 1000 == pytest.approx(high - low - 2.0, abs=0.8)
    listed = json.loads((out / 'symmetries.json').read_text())
    assert sorted(listed) == sorted(specs)
    assert json.loads((out / 'family.json').read_text())['parts'] == specs


def test_without_a_seed_the_fixed_parts_and_count_needs_a_seed(tmp_path, capsys):
    assert main(['parts', 'generate', '--out', str(tmp_path / 'f'), '--names', 'tube']) == 0
    assert sorted(p.name for p in (tmp_path / 'f').iterdir()) == ['symmetries.json', 'tube.stl']
    assert main(['parts', 'generate', '--out', str(tmp_path / 'g'), '--count', '3']) == 1
    assert '--count needs --seed' in capsys.readouterr().err
    assert main(['parts', 'generate', '--out', str(tmp_path / 'g'), '--seed', '3',
                 '--names', 'tube']) == 1
    assert 'choose from' in capsys.readouterr().err
    assert main(['parts', 'generate', '--out', str(tmp_path / 'h'), '--seed', '3', '--count',
                 '4', '--names', 'plate_3b']) == 0
    assert sorted(p.name for p in (tmp_path / 'h').iterdir()) == [
        'family.json', 'plate_3b.stl', 'symmetries.json']
