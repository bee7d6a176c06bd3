"""A cell's bag made ready for a replay through the graph (``tlessbot approve`` / ``check``).

Cells record their cameras as realsense-ros names them: ``/top/color/image_raw``, or under a
namespace remap ``/top/top/color/image_raw`` or ``/cell/top/...`` (realsense-ros 4.5x puts a
camera at ``/<camera_namespace>/<camera_name>``; its default ``/camera/camera``). And
``ros2 bag record`` logs each message when it arrived, so one frame's images carry several log
times, unlike the bags tlessbot writes.

:func:`find_cameras` finds each graph camera's topic prefix; :func:`stage_bag` copies the
messages the graph reads (colour, aligned depth, its camera_info, per camera) into a new bag
under the graph's names, one frame per log time: the side colour image's stamp, the top
camera's nearest frame within ``sync.max_age_s`` (a bag of one camera: its colour stamp). A
lock-step replay then sends whole frames, one at a time, in the same order every run. A frame
one of the cameras lacks a message of is left out and counted.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from tlessbot_ros.conversions.topics import COLOR, COLOR_INFO, DEPTH, DEPTH_INFO, camera_topic
from tlessbot_ros.core.label_views import view_order
from tlessbot_ros.errors import BagError
from tlessbot_ros.io.bags import BagMessage

# What the stages read of each camera (nodes/stage.py CAMERA_INPUTS); colour camera_info is
# copied when the bag has it.
NEEDED = (COLOR, DEPTH, DEPTH_INFO)
OPTIONAL = (COLOR_INFO,)
WHY = {COLOR: 'colour', DEPTH: 'aligned depth (realsense-ros align_depth.enable:=true)',
       DEPTH_INFO: 'aligned depth camera_info'}


class SetupError(BagError):
    """The bag cannot be replayed through the graph as it is (exit 2 of ``tlessbot check``)."""


def parse_camera_map(values: Sequence[str] | None) -> dict[str, str]:
    """``['side=/camera/camera']`` -> ``{'side': '/camera/camera'}``."""
    mapping = {}
    for value in values or ():
        name, sep, prefix = value.partition('=')
        if not sep or not name or not prefix.startswith('/'):
            raise SetupError(f'--camera wants NAME=/PREFIX (e.g. side=/camera/camera), got '
                             f'{value!r}')
        mapping[name] = prefix.rstrip('/')
    return mapping


def _prefixes(topics: Sequence[str]) -> list[str]:
    """Topic prefixes that carry a colour image (``/a/b`` of ``/a/b/color/image_raw``)."""
    suffix = '/' + COLOR
    return sorted(t[:-len(suffix)] for t in topics if t.endswith(suffix) and
                  len(t) > len(suffix))


def find_cameras(topics: Sequence[str], cameras: Sequence[str],
                 given: Mapping[str, str] | None = None, *, bag: str = 'bag'
                 ) -> dict[str, str]:
    """{graph camera: topic prefix in the bag}: the cameras the graph runs with.

    A camera's prefix is ``given`` or found: ``/<camera>``, else the one prefix that ends in
    ``/<camera>`` (``/top/top``, ``/cell/top``). A bag of one camera is a rig of one camera:
    the one of ``cameras`` it has topics of, else, when it has the topics of one camera only,
    that camera under its prefix's last name (``/camera/camera``: ``camera``). One ``given``
    name outside ``cameras`` (``--camera front=/cell/front``) is such a camera too.

    Raises:
        SetupError: no camera found, or a camera's prefix lacks a topic a stage needs; the
            line names the topics.
    """
    given = dict(given or {})
    unknown = sorted(set(given) - set(cameras))
    if unknown and len(given) > 1:
        raise SetupError(f"--camera names {unknown}; the graph's cameras are {list(cameras)} "
                         '(or one --camera NAME=PREFIX alone: a rig of one camera)')
    if len(set(given.values())) < len(given):
        raise SetupError(f'--camera maps two cameras to one prefix ({given}); the graph fuses '
                         'two different views')
    prefixes = _prefixes(topics)
    found: dict[str, str] = dict(given) if unknown else _by_name(prefixes, cameras, given)
    others = [p for p in prefixes if p not in found.values()]
    if not found and len(others) == 1:
        found, others = {others[0].rsplit('/', 1)[-1]: others[0]}, []
    missing_cameras = [c for c in cameras if c not in found]
    # a camera missing while the bag has another one's topics: which is which is not clear
    if not found or (missing_cameras and others and not unknown):
        hint = (f'; it has camera topics under {", ".join(others)}: map them with --camera '
                f'{missing_cameras[0]}={others[0]}' if others else '')
        needed = ', '.join(camera_topic(c, t) for c in missing_cameras for t in NEEDED)
        raise SetupError(f'{bag} lacks the topics of camera(s) {", ".join(missing_cameras)} '
                         f'(the graph fuses {" and ".join(cameras)}, or runs on one camera): '
                         f'{needed}{hint}')
    absent = [(f'{prefix}/{t}', t) for prefix in found.values() for t in NEEDED
              if f'{prefix}/{t}' not in topics]
    if absent:
        what = '; '.join(dict.fromkeys(WHY[t] for _, t in absent))
        raise SetupError(f'{bag} lacks {", ".join(t for t, _ in absent)} (the stages need '
                         f'the {what})')
    return found


def replay_cameras(bag: str | Path, cameras: Sequence[str]) -> list[str] | None:
    """The ``rig.cameras`` a graph fed by a plain replay of ``bag`` runs with: the one camera
    of a bag of one camera under the graph's names (``/side/...``); None when the bag is
    another (two cameras, other names, topics missing: the graph keeps ``cameras``)."""
    from tlessbot_ros.io.bags import bag_topics

    try:
        found = find_cameras(list(bag_topics(bag)), cameras, bag=str(bag))
    except BagError:
        return None
    if set(found) == set(cameras) or any(p != f'/{c}' for c, p in found.items()):
        return None
    return list(found)


def _by_name(prefixes: Sequence[str], cameras: Sequence[str], given: Mapping[str, str]
             ) -> dict[str, str]:
    """{camera: prefix} of the ``cameras`` found: ``given``, ``/<camera>`` or the one prefix
    ending in ``/<camera>``."""
    found: dict[str, str] = {}
    for camera in cameras:
        if camera in given:
            found[camera] = given[camera]
            continue
        exact = f'/{camera}'
        ending = [p for p in prefixes if p.endswith(exact)]
        if exact in ending:
            found[camera] = exact
        elif len(ending) == 1:
            found[camera] = ending[0]
    return found


@dataclass
class StagedBag:
    """A bag :func:`stage_bag` wrote, and what it made of the source."""

    path: Path
    cameras: dict[str, str]                 # graph camera -> prefix in the source bag
    frames: list[int] = field(default_factory=list)   # main camera's colour stamps, ns
    skipped: int = 0                        # its frames left out: a message missing


def _stamped(bag: str | Path, sources: Mapping[str, tuple[str, str]]
             ) -> Iterator[tuple[tuple[str, str], int, BagMessage]]:
    """((camera, relative topic), header stamp, message) of the ``sources`` topics."""
    from tlessbot_ros.conversions.cdr import header_stamp_ns
    from tlessbot_ros.io.bags import read_bag

    for message in read_bag(bag, list(sources)):
        try:
            stamp = header_stamp_ns(message.raw)
        except ValueError:
            raise SetupError(f'{bag}: a message on {message.topic} has no header') from None
        yield sources[message.topic], stamp, message


def _nearest(stamps: Sequence[int], stamp: int) -> int | None:
    return min(stamps, key=lambda s: abs(s - stamp)) if stamps else None


def _frame(stamps: Mapping[tuple[str, str], set[int]], cameras: Sequence[str],
           relatives: Sequence[str], stamp: int, max_age_ns: int
           ) -> list[tuple[str, str, int]] | None:
    """The messages (camera, relative topic, stamp) of the frame of main camera stamp
    ``stamp`` (``cameras[0]``); None when a camera has no frame within ``max_age_ns`` or lacks
    a needed message of it."""
    frame = []
    for camera in cameras:
        own = stamp if camera == cameras[0] else _nearest(sorted(stamps.get((camera, COLOR), ())),
                                                    stamp)
        if own is None or abs(own - stamp) > max_age_ns:
            return None
        for rel in relatives:
            if own in stamps.get((camera, rel), ()):
                frame.append((camera, rel, own))
            elif rel in NEEDED:
                return None
    return frame


def stage_bag(bag: str | Path, out: str | Path, cameras: Mapping[str, str], *,
              max_age_s: float = 0.050) -> StagedBag:
    """Copy the frames of ``bag`` the graph reads to a new mcap bag ``out``, under the graph's
    topic names, one log time (the colour stamp of the side camera, or of a rig's one camera)
    per whole frame. Two passes over the bag
    (the stamps, then the messages), so a long bag is never held in memory.

    Args:
        cameras: {graph camera: prefix in ``bag``} (:func:`find_cameras`).
        max_age_s: largest stamp difference between the side frame and the other cameras'
            frames joined to it (seconds; the nodes' ``sync.max_age_s``).
    """
    from tlessbot_ros.io.bag_writer import BagWriter
    from tlessbot_ros.io.bags import bag_topics

    available = bag_topics(bag)
    sources = {f'{prefix}/{rel}': (camera, rel) for camera, prefix in cameras.items()
               for rel in (*NEEDED, *OPTIONAL) if f'{prefix}/{rel}' in available}
    stamps: dict[tuple[str, str], set[int]] = {}
    for key, stamp, _ in _stamped(bag, sources):
        stamps.setdefault(key, set()).add(stamp)
    staged = StagedBag(Path(out), dict(cameras))
    present = sorted({rel for _, rel in stamps})
    log_times: dict[tuple[str, str, int], list[int]] = {}   # a message -> its frames' stamps
    order = view_order(cameras)   # the main camera first
    for stamp in sorted(stamps.get((order[0], COLOR), ())):
        frame = _frame(stamps, order, present, stamp, int(max_age_s * 1e9))
        if frame is None:
            staged.skipped += 1
            continue
        staged.frames.append(stamp)
        for member in frame:
            log_times.setdefault(member, []).append(stamp)
    with BagWriter(out) as writer:   # readers sort by log time: the write order is free
        types = {rel: available[f'{cameras[c]}/{rel}'] for c, rel in stamps}
        for camera in cameras:
            for rel in present:
                writer.add_topic(camera_topic(camera, rel), types[rel])
        for (camera, rel), stamp, message in _stamped(bag, sources):
            for log_time in log_times.pop((camera, rel, stamp), ()):
                writer.write(camera_topic(camera, rel), log_time, message.raw)
    if not staged.frames:
        raise SetupError(f'{bag}: no whole frame (colour, aligned depth and its camera_info of '
                         f'{" and ".join(cameras)} within {1e3 * max_age_s:.0f} ms)')
    return staged
