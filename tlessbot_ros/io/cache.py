"""Start-up caches kept between runs: what the pose stage derives from a template database.

The arrays (:mod:`tlessbot_ros.core.pose.derived`) go to one uncompressed ``.npz`` per
templates file, named by the file's SHA-256, in ``$TLESSBOT_CACHE_DIR``, else
``$XDG_CACHE_HOME/tlessbot_ros``, else ``~/.cache/tlessbot_ros``. A changed templates file
gets a new name, so a stale cache is never read; an unreadable or foreign one is ignored and
rebuilt. Writing is atomic (a temporary file renamed into place), so two processes that start
together (the pose node and its worker) never read half a file. A cache that cannot be
written (a read-only home) only costs the next start its time.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tlessbot_ros.core.pose import (
    DERIVED_VERSION,
    TemplateDatabase,
    derived_arrays,
    restore_derived,
)


def cache_dir(environ: dict[str, str] | None = None) -> Path:
    """Where start-up caches live (see the module docstring)."""
    env = os.environ if environ is None else environ
    if env.get('TLESSBOT_CACHE_DIR'):
        return Path(env['TLESSBOT_CACHE_DIR'])
    base = Path(env['XDG_CACHE_HOME']) if env.get('XDG_CACHE_HOME') else \
        Path(env.get('HOME', '~')).expanduser() / '.cache'
    return base / 'tlessbot_ros'


def file_fingerprint(path: str | Path) -> str:
    """SHA-256 (hex) of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, 'rb') as handle:
        for block in iter(lambda: handle.read(1 << 20), b''):
            digest.update(block)
    return digest.hexdigest()


def derived_cache_path(templates_path: str | Path, *, fingerprint: str | None = None,
                       directory: Path | None = None) -> Path:
    """The cache file of one templates file."""
    fingerprint = fingerprint or file_fingerprint(templates_path)
    return (directory or cache_dir()) / f'templates-{fingerprint[:24]}-v{DERIVED_VERSION}.npz'


@dataclass(frozen=True)
class WarmUpReport:
    """How a pose stage got ready: from the cache or by building, and how long it took (s)."""

    from_cache: bool
    stored: Path | None
    seconds: float


def load_derived(database: TemplateDatabase, templates_path: str | Path, *,
                 directory: Path | None = None, fingerprint: str | None = None) -> bool:
    """Restore the database's derived arrays from the cache; False when there is none
    (``fingerprint``: the templates file's, when the caller has it already)."""
    fingerprint = fingerprint or file_fingerprint(templates_path)
    path = derived_cache_path(templates_path, fingerprint=fingerprint, directory=directory)
    try:
        with np.load(path, allow_pickle=False) as data:
            return restore_derived(database, data, fingerprint=fingerprint)
    except Exception:  # missing, unreadable, or truncated by a crash mid-write elsewhere
        return False


def store_derived(database: TemplateDatabase, templates_path: str | Path, *,
                  directory: Path | None = None, fingerprint: str | None = None
                  ) -> Path | None:
    """Write the database's derived arrays (built where missing) to the cache; the path, or
    None when it cannot be written."""
    fingerprint = fingerprint or file_fingerprint(templates_path)
    path = derived_cache_path(templates_path, fingerprint=fingerprint, directory=directory)
    arrays = derived_arrays(database, fingerprint=fingerprint)
    tmp_name = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix='.tmp', delete=False) as tmp:
            tmp_name = tmp.name
            np.savez(tmp, **arrays)
        os.chmod(tmp_name, 0o644)   # readable by the user's other tools, like any cache
        os.replace(tmp_name, path)
    except OSError:
        if tmp_name is not None:   # a full disk: leave no half-written file behind
            Path(tmp_name).unlink(missing_ok=True)
        return None
    return path


def warm_pose_stage(pipeline, templates_path: str | Path, *,
                    directory: Path | None = None, colour: bool = True) -> WarmUpReport:
    """Ready a :class:`~tlessbot_ros.core.pipeline.PerceptionPipeline`'s pose stage: restore
    the derived arrays from the cache when it has them, then run its warm-up (which also
    compiles the numba kernels, cached by numba on disk; ``colour``: whether frames will bring
    colour images); store the arrays when they were built here."""
    started = time.perf_counter()
    database = pipeline.pose_estimator.database
    fingerprint = file_fingerprint(templates_path)
    from_cache = load_derived(database, templates_path, directory=directory,
                              fingerprint=fingerprint)
    pipeline.warm_up(colour=colour)
    stored = None if from_cache else store_derived(database, templates_path,
                                                   directory=directory, fingerprint=fingerprint)
    return WarmUpReport(from_cache, stored, time.perf_counter() - started)
