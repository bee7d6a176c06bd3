"""``NAME=VALUE`` command-line overrides of a frozen ``*Params`` dataclass (for sweeps)."""
from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any, TypeVar

from tlessbot_ros.errors import TlessbotError

Params = TypeVar('Params')


def _parse(text: str, default: Any, name: str) -> Any:
    try:
        if isinstance(default, bool):
            if text.lower() not in ('true', 'false', '1', '0'):
                raise ValueError(text)
            return text.lower() in ('true', '1')
        return type(default)(text)
    except ValueError:
        raise TlessbotError(f'{name}: cannot read {text!r} as {type(default).__name__}') from None


def apply_overrides(params: Params, assignments: Iterable[str] | None) -> Params:
    """``params`` with each ``'field=value'`` applied (value read as the field's type)."""
    fields = {f.name for f in dataclasses.fields(params)}
    changes = {}
    for assignment in assignments or []:
        name, sep, text = assignment.partition('=')
        if not sep or name not in fields:
            raise TlessbotError(f'expected NAME=VALUE with NAME one of '
                                f'{", ".join(sorted(fields))}; got {assignment!r}')
        changes[name] = _parse(text, getattr(params, name), name)
    return dataclasses.replace(params, **changes)
