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

__all__ = ['InstanceTracker', 'Observation', 'TrackParams', 'TrackedPart', 'nearest_equivalent']
