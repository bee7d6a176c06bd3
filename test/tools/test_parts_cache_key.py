"""The cached parts folder of `tlessbot evaluate --models CAD` follows the code that makes
templates: an upgrade that changes how templates are built does not serve the old ones."""
import shutil
from pathlib import Path

import numpy as np

import tlessbot_ros
from tlessbot_ros.tools.support.parts_build import (
    TEMPLATE_CODE,
    BuildOptions,
    parts_cache_name,
    template_code_fingerprint,
)


def _copy_of_the_template_code(tmp_path: Path) -> Path:
    package = Path(tlessbot_ros.__file__).parent
    root = tmp_path / 'pkg'
    for entry in TEMPLATE_CODE:
        source, target = package / entry, root / entry
        target.parent.mkdir(parents=True, exist_ok=True)
        if source.is_dir():
            shutil.copytree(source, target, ignore=shutil.ignore_patterns('__pycache__'))
        else:
            shutil.copy(source, target)
    (root / 'nodes').mkdir()
    (root / 'nodes' / 'pose.py').write_text('# a node\n')
    return root


def test_a_change_to_the_template_code_changes_the_fingerprint(tmp_path):
    root = _copy_of_the_template_code(tmp_path)
    before = template_code_fingerprint(root)
    assert before == template_code_fingerprint(Path(tlessbot_ros.__file__).parent)
    (root / 'nodes' / 'pose.py').write_text('# another node\n')   # not template code
    assert template_code_fingerprint(root) == before
    building = root / 'core' / 'pose' / 'building.py'
    building.write_text(building.read_text() + '\n# a change\n')
    assert template_code_fingerprint(root) != before


def test_the_cache_name_holds_the_cad_content_and_the_code(tmp_path):
    cad = tmp_path / 'cad'
    cad.mkdir()
    (cad / 'plate.stl').write_bytes(_box_stl())
    options = BuildOptions()
    name = parts_cache_name(cad, options, code='a' * 64)
    assert name == parts_cache_name(cad, options, code='a' * 64)
    assert name != parts_cache_name(cad, options, code='b' * 64)
    # a folder built with another share of smoothed training depth is another folder
    other_depth = BuildOptions(smoothed_share=0.5)
    assert name != parts_cache_name(cad, other_depth, code='a' * 64)
    (cad / 'plate.stl').write_bytes(_box_stl(scale=2.0))
    assert name != parts_cache_name(cad, options, code='a' * 64)


def _box_stl(scale: float = 1.0) -> bytes:
    """A closed 20 x 10 x 4 mm box (ASCII STL) times ``scale``."""
    corners = np.array([[x, y, z] for x in (0, 20) for y in (0, 10) for z in (0, 4)]) * scale
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    lines = ['solid box']
    for a, b, c, d in quads:
        for tri in ((a, b, c), (a, c, d)):
            lines += ['facet normal 0 0 0', 'outer loop']
            lines += [f'vertex {v[0]} {v[1]} {v[2]}' for v in corners[list(tri)]]
            lines += ['endloop', 'endfacet']
    return ('\n'.join(lines + ['endsolid box']) + '\n').encode()
