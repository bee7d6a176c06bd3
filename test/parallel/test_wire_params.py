"""Stage parameters reach the pose workers as JSON and come back equal, nested ones too."""
from __future__ import annotations

import json
import math

import pytest

from tlessbot_ros.core.pipeline import FitParams
from tlessbot_ros.core.pose import PoseParams
from tlessbot_ros.parallel.wire import WireError, params_from_json, params_to_json


@pytest.mark.parametrize('params', [FitParams(verify_accept_fitness=0.95, lookalike_check=False),
                                    PoseParams()])
def test_params_survive_the_json_trip(params):
    assert params_from_json(type(params), json.loads(json.dumps(params_to_json(params)))) == \
        params


def test_missing_fields_keep_defaults_unknown_ones_fail_and_values_are_validated():
    assert params_from_json(FitParams, {}) == FitParams()
    with pytest.raises(WireError, match='no field'):
        params_from_json(FitParams, {'min_fitness': 0.3})
    with pytest.raises(ValueError, match='lookalike_tolerance_m'):
        params_from_json(FitParams, {'lookalike_tolerance_m': -1.0})
    assert math.isinf(params_from_json(FitParams, json.loads(json.dumps(
        {'verify_accept_fitness': math.inf}))).verify_accept_fitness)
