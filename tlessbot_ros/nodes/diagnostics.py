"""Building diagnostic_msgs/DiagnosticArray messages for /diagnostics."""
from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR


def diagnostic_array(stamp: Any, name: str, level: bytes, message: str,
                     values: dict[str, Any], hardware_id: str = '') -> DiagnosticArray:
    """A one-status DiagnosticArray; values are rendered with str()."""
    status = DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
    array = DiagnosticArray(status=[status])
    array.header.stamp = stamp
    return array
