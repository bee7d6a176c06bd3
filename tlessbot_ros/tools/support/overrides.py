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
        if isinstance(default, tuple):  # 'a,b' for a (min, max) pair
            values = text.split(',')
            if len(values) != len(default):
                raise ValueError(text)
            return tuple(type(d)(v) for d, v in zip(default, values))
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


def stage_overrides(assignments: Iterable[str] | None) -> dict[str, Any]:
    """``NAME=VALUE`` overrides sent each to the pipeline stage dataclass that has the field
    NAME (LocaliseParams, ClassifyParams, FitParams, SegmentationParams, FusionParams; no field
    name is in two of them), as PerceptionPipeline keyword arguments; a value the dataclass
    rejects is reported in one line, with its reason."""
    from tlessbot_ros.core.localise import FusionParams, SegmentationParams
    from tlessbot_ros.core.params import ClassifyParams, FitParams, LocaliseParams

    stages: dict[str, Any] = {'localise_params': LocaliseParams(),
                              'classify_params': ClassifyParams(), 'fit_params': FitParams(),
                              'segmentation': SegmentationParams(), 'fusion': FusionParams()}
    owner = {f.name: key for key, params in stages.items() for f in dataclasses.fields(params)}
    for assignment in assignments or []:
        key = owner.get(assignment.partition('=')[0])
        if key is None:
            raise TlessbotError(f'expected NAME=VALUE with NAME one of '
                                f'{", ".join(sorted(owner))}; got {assignment!r}')
        try:
            stages[key] = apply_overrides(stages[key], [assignment])
        except ValueError as error:   # the dataclass's validation says how to fix it
            raise TlessbotError(f'{assignment}: {error}') from None
    return stages
