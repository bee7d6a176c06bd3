"""JUnit XML of ``tlessbot check``'s outcome: one test case per part of each frame, the
format CI services show (GitHub Actions through a reporter action, GitLab, Jenkins)."""
from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

from tlessbot_ros.core.regression import PartCheck


def junit_xml(checks: Sequence[PartCheck], *, suite: str, frame_index: dict[int, int],
              seconds: float = 0.0) -> str:
    """A ``<testsuites>`` document: a case ``frame NNN <part>`` (class ``suite``) per check,
    with a ``<failure>`` that says what changed when the part does not match."""
    failures = sum(not c.ok for c in checks)
    root = ET.Element('testsuites', name='tlessbot check', tests=str(len(checks)),
                      failures=str(failures), errors='0', time=f'{seconds:.3f}')
    node = ET.SubElement(root, 'testsuite', name=suite, tests=str(len(checks)),
                         failures=str(failures), errors='0', skipped='0', time=f'{seconds:.3f}')
    for check in checks:
        frame = frame_index.get(check.stamp_ns, -1)
        case = ET.SubElement(node, 'testcase', classname=suite,
                             name=f'frame {frame:03d} (stamp {check.stamp_ns}) {check.name}',
                             time='0')
        if not check.ok:
            failure = ET.SubElement(case, 'failure', message=check.describe(),
                                    type=check.status)
            failure.text = f'frame {frame} (stamp {check.stamp_ns} ns), {check.name}: ' \
                           f'{check.describe()}'
        else:
            ET.SubElement(case, 'system-out').text = check.describe()
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, 'unicode') + '\n'


def write_junit(path: str | Path, checks: Sequence[PartCheck], **kwargs) -> None:
    Path(path).write_text(junit_xml(checks, **kwargs), encoding='utf-8')
