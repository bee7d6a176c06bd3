"""What a ROS process of the package sets up before its first node: the package's Fast DDS
profile (config/fastdds.xml), glibc's allocator told to keep image-sized buffers, BLAS on one
thread, and ``rclpy.init`` with :mod:`~tlessbot_ros.nodes.signals`' handlers (:func:`init_ros`).
"""
from __future__ import annotations

import os

from tlessbot_ros.nodes.signals import interrupt_on_signals

DDS_PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def use_package_dds_profile(environ: dict[str, str] | None = None) -> str | None:
    """Point Fast DDS at config/fastdds.xml (large shared-memory segments, so camera images
    are not fragmented and repaired), unless the user chose a profile or another middleware.

    Must run before the process's first ``rclpy.init``; child processes inherit it through
    ``environ`` (default ``os.environ``). Returns the profile path set, or None.
    """
    from tlessbot_ros.io.config import package_path

    environ = os.environ if environ is None else environ
    if any(environ.get(name) for name in DDS_PROFILE_VARIABLES):
        return None
    if 'fastrtps' not in environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp'):
        return None
    profile = package_path('config', 'fastdds.xml')
    if not profile.is_file():
        return None
    for name in DDS_PROFILE_VARIABLES:
        environ[name] = str(profile)
    return str(profile)


# mallopt(3) parameters of glibc's malloc.h.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
MALLOC_VARIABLES = ('MALLOC_MMAP_THRESHOLD_', 'MALLOC_TRIM_THRESHOLD_')


def keep_freed_buffers(*, mmap_threshold: int = 32 << 20, trim_threshold: int = 64 << 20,
                       environ: dict[str, str] | None = None) -> bool:
    """Make glibc's malloc serve image-sized blocks from the heap and keep freed memory.

    Every received image (0.6-0.9 MiB) passes through a few freshly allocated buffers (the
    middleware's copy, the serialised bytes, numpy arrays). By default glibc maps blocks this
    large with mmap, or trims the heap once they are freed, so each message pays for new
    zero-filled pages (docs/design.md, docs/bench/code-figures.md). Memory freed stays with
    the process, up to ``trim_threshold`` bytes above what it uses.

    Does nothing (returns False) off glibc or when the user set MALLOC_MMAP_THRESHOLD_ or
    MALLOC_TRIM_THRESHOLD_ (mallopt would override their choice).
    """
    import ctypes

    environ = os.environ if environ is None else environ
    if any(name in environ for name in MALLOC_VARIABLES):
        return False
    try:
        libc = ctypes.CDLL('libc.so.6')
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))
                and mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)))


def init_ros(args: list[str] | None = None) -> None:
    """``rclpy.init`` after :func:`use_package_dds_profile` and :func:`keep_freed_buffers`,
    with :func:`interrupt_on_signals` instead of rclpy's signal handlers."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    use_package_dds_profile()
    keep_freed_buffers()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    interrupt_on_signals()


BLAS_THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')


def limit_blas_threads() -> int | None:
    """Run this process's BLAS on one thread, unless the user set a thread count.

    The stages already run in parallel, one process each, on a few cores. OpenBLAS's worker
    threads spin while they wait for work, so a node that multiplies a few mid-sized matrices
    per frame (the classifier's feature map) kept most of a core busy and slowed the other
    stages (paired runs: docs/design.md, "How frames flow"). The environment variables also reach
    worker processes started later.

    Returns:
        The thread limit applied, or None when one of ``BLAS_THREAD_VARIABLES`` was set.
    """
    if any(name in os.environ for name in BLAS_THREAD_VARIABLES):
        return None
    os.environ['OPENBLAS_NUM_THREADS'] = os.environ['OMP_NUM_THREADS'] = '1'
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api='blas')
    return 1
