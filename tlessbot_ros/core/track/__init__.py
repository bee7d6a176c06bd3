"""Instance tracking for the arm's side: names that hold while a part stays where it is.

This package's public API."""
from __future__ import annotations

from tlessbot_ros.core.track.instances import (
    InstanceTracker,
    Observation,
    TrackedPart,
    TrackParams,
    nearest_equivalent,
)
from tlessbot_ros.core.track.requests import Request, RequestBook

__all__ = ['InstanceTracker', 'Observation', 'Request', 'RequestBook', 'TrackParams',
           'TrackedPart', 'nearest_equivalent']
