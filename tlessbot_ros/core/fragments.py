"""One part, one pose: fragments of an over-segmented part are dropped, deterministically.

When the localiser splits one part into two or three instances (in both views alike, so the
fusion keeps them apart), each piece is fitted and the part is published several times, the
fits within a centimetre or two of each other. Two rigid parts cannot sit inside each other,
so of two detections whose fitted centres lie closer than ``overlap`` x the smaller diameter,
the one that fits worse (pose fitness, then fewer ROI points) is a fragment of the other.

The pose stage publishes each part as soon as it is fitted, and parts fitted in worker
processes complete in any order; the answer must not depend on that order. So detections that
could overlap (ROI centroids within half their summed diameters), and the detections those
could overlap in turn, are decided together, in instance order, once the last of them is
fitted: a part with no such neighbour goes out at once. (Deciding a piece as soon as its own
neighbours are fitted would hand a keeper to ``publish`` before a neighbour's piece that
waits for a third part could join it: the join would depend on which was fitted first.)

A piece is also a fragment of a neighbour whose fit explains it (``explains``, see
:mod:`tlessbot_ros.core.one_part`): one part the fusion divided, fitted whole on one piece.
A dropped piece that its keeper's fit explains is in :attr:`FragmentFilter.kept_by`, so its
region can join the keeper (a piece dropped for its fitted centre alone keeps its region: two
thin parts on top of each other fit one pose; unless ``same`` below holds). So is a piece
that one fit of both explains (``joins``, :mod:`tlessbot_ros.core.piece_union`: two halves of
a part, each fitted over its own half), asked only while the keeper is not yet handed to
``publish`` (it takes that fit).
A piece whose region is a band along a fitted neighbour's edge (``band``,
:mod:`tlessbot_ros.core.edge_bands`) is dropped first, its region in :attr:`erased`. A piece
whose fit fills the same space as a better neighbour's fit of its class (``same``,
:mod:`tlessbot_ros.core.same_part`; asked after ``joins``) is one part fitted twice: dropped,
its region joins it.
"""
from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

import numpy as np

from tlessbot_ros.core.common import transform_points

if TYPE_CHECKING:
    from tlessbot_ros.core.frame import Detection, PartJob
    from tlessbot_ros.core.pose import TemplateDatabase


class _Numbered(Protocol):
    @property
    def instance_id(self) -> int: ...


D = TypeVar('D', bound=_Numbered)


@dataclass
class _Piece(Generic[D]):
    detection: D
    frame: str            # the frame its positions are in: 'world', or one camera's name
    centroid: np.ndarray  # (3,) ROI centroid, metres
    points: int           # ROI points
    diameter_m: float     # of its first class candidate
    neighbours: list[int] = field(default_factory=list)
    group: list[int] = field(default_factory=list)   # the pieces decided with it
    centre: np.ndarray | None = None
    score: float = -np.inf   # pose fitness
    fitted_diameter_m: float = 0.0
    done: bool = False
    decided: bool = False


class FragmentFilter(Generic[D]):
    """Hands each fitted detection to ``publish`` unless it is a fragment of a larger one.

    Args:
        pieces: per detection (any object with ``instance_id``), its ROI centroid (3,), the name
            of the frame that centroid is in (the world when the camera's pose over the table
            is known, else its camera: pieces in different frames are never compared), its ROI
            point count and its first class candidate's diameter in metres.
        publish: called once per kept detection, in an order that depends on completion.
        overlap: fraction of the smaller diameter under which two fitted centres are one part
            (0: keep everything).
        explains: ``explains(a, b)``: whether ``a``'s fit explains ``b``'s depth points (both
            fitted neighbours); None: centres only.
        joins: ``joins(keeper, piece)``: whether one fit of both explains each (``keeper``
            then takes it); asked of neighbours neither fit explains. None: never.
        touching: ``touching(a, b)``: pieces whose regions touch are neighbours too, and a
            piece with no pose is asked to join them. None: centroids only.
        band: ``band(piece, other)``: whether ``piece``'s region is a band along fitted
            ``other``'s edge: dropped, its id in :attr:`erased`. None: never.
        same: ``same(a, b)``: whether two fitted neighbours are one part fitted twice (the
            worse is dropped, its region joins the better). None: never.
    """

    def __init__(self, pieces: Sequence[tuple[D, np.ndarray, str, int, float]],
                 publish: Callable[[D], None], *, overlap: float,
                 explains: Callable[[D, D], bool] | None = None,
                 joins: Callable[[D, D], bool] | None = None,
                 touching: Callable[[D, D], bool] | None = None,
                 band: Callable[[D, D], bool] | None = None,
                 same: Callable[[D, D], bool] | None = None) -> None:
        self._publish = publish
        self._band = band
        self._same = same
        self.erased: set[int] = set()   # ids of dropped pieces that are a neighbour's edge
        self._overlap = float(overlap)
        self._explains = explains
        self._joins = joins
        self._published: set[int] = set()   # ids of the detections handed to publish
        self._joins_asked: dict[tuple[int, int], bool] = {}
        self._lock = threading.Lock()
        self.dropped: list[D] = []
        # id(dropped detection) -> the detection whose fit explains it
        self.kept_by: dict[int, D] = {}
        self._pieces = [_Piece(d, frame, np.asarray(c, np.float64), int(n), float(diam))
                        for d, c, frame, n, diam in pieces]
        self._index = {id(p.detection): k for k, p in enumerate(self._pieces)}
        self._touching = touching
        for a, piece in enumerate(self._pieces):
            for b in range(a + 1, len(self._pieces)):
                if self._neighbours(piece, self._pieces[b]):
                    piece.neighbours.append(b)
                    self._pieces[b].neighbours.append(a)
        for a, piece in enumerate(self._pieces):
            if not piece.group:
                group = _connected(self._pieces, a)
                for k in group:
                    self._pieces[k].group = group

    def _neighbours(self, piece: _Piece[D], other: _Piece[D]) -> bool:
        """Whether two pieces could overlap: ROI centroids within half their summed diameters,
        or (``touching``) regions that touch: a part's two halves, one of them off the part,
        can have centroids farther apart than that."""
        if self._overlap <= 0 or other.frame != piece.frame:
            return False
        return bool(np.linalg.norm(other.centroid - piece.centroid)
                    < 0.5 * (other.diameter_m + piece.diameter_m)) or \
            self._touching is not None and self._touching(piece.detection, other.detection)

    def fitted(self, detection: D, centre: np.ndarray | None, diameter_m: float,
               score: float) -> None:
        """``detection``'s fit is done: its fitted centre (3,) in its piece's frame (None: no
        pose), its fitted class's diameter and its pose fitness (higher is better); publishes
        what can be decided now."""
        with self._lock:
            piece = self._pieces[self._index[id(detection)]]
            piece.done, piece.fitted_diameter_m = True, float(diameter_m)
            piece.centre = None if centre is None else np.asarray(centre, np.float64)
            piece.score = float(score)
            ready = self._decide_ready()
            self._published.update(id(kept) for kept in ready)
        for kept in ready:
            self._publish(kept)

    def _decide_ready(self) -> list[D]:
        """Decide every piece whose group (its neighbours, theirs in turn...) is all fitted."""
        kept = []
        for piece in self._pieces:
            if piece.decided or not all(self._pieces[b].done for b in piece.group):
                continue
            piece.decided = True
            if (keeper := self._edge_of(piece) or self._fragment_of(piece)) is not None:
                self.dropped.append(piece.detection)
                if id(piece.detection) in self.erased:
                    continue
                if self._explains is not None and self._explains(keeper, piece.detection) or \
                        self._joined(keeper, piece.detection) or \
                        self._same_part(keeper, piece.detection):
                    self.kept_by[id(piece.detection)] = keeper
            else:
                kept.append(piece.detection)
        return kept

    def _edge_of(self, piece: _Piece[D]) -> D | None:
        """The first fitted neighbour whose edge ``piece``'s region is a band along
        (``band``), if any; the piece is then in :attr:`erased`."""
        if self._band is None:
            return None
        for b in piece.neighbours:
            other = self._pieces[b]
            if other.centre is not None and self._band(piece.detection, other.detection):
                self.erased.add(id(piece.detection))
                return other.detection
        return None

    def _fragment_of(self, piece: _Piece[D]) -> D | None:
        """The neighbour this piece is a fragment of, if any: one whose fit explains it where
        its own fit does not explain the other, or one that fits better and sits on its
        fitted centre or (each explaining the other) is the same part. A piece with no pose
        is one only of a touching neighbour whose joint fit explains each."""
        if piece.centre is None:
            return self._unfitted_joins(piece)
        explains = self._explains or (lambda a, b: False)
        for b in piece.neighbours:
            other = self._pieces[b]
            if other.centre is None:
                continue
            limit = self._overlap * min(piece.fitted_diameter_m, other.fitted_diameter_m)
            explained = explains(other.detection, piece.detection)
            if explained != explains(piece.detection, other.detection):
                if explained:   # only the other's fit explains both: this is its piece
                    return other.detection
                continue
            if (explained or np.linalg.norm(other.centre - piece.centre) < limit) and \
                    not _better(piece, other):
                return other.detection
            if not explained and not _better(piece, other) and \
                    self._joined(other.detection, piece.detection):
                return other.detection
            # after the joint fit, which refits both pieces where it holds
            if not _better(piece, other) and self._same_part(piece.detection, other.detection):
                return other.detection
        return None

    def _same_part(self, a: D, b: D) -> bool:
        """``same(a, b)``: both fitted, one part fitted twice (False without ``same``)."""
        return self._same is not None and self._same(a, b)

    def _unfitted_joins(self, piece: _Piece[D]) -> D | None:
        """The first neighbour touching ``piece`` (no pose: named unknown) that one fit of both
        explains (``joins``), if any: a fitted one, or a better unknown one (more points)."""
        if self._touching is None:
            return None
        for b in piece.neighbours:
            other = self._pieces[b]
            if (other.centre is not None or _better(other, piece)) and \
                    self._touching(other.detection, piece.detection) and \
                    self._joined(other.detection, piece.detection):
                return other.detection
        return None

    def _joined(self, keeper: D, piece: D) -> bool:
        """``joins(keeper, piece)`` (asked once) while ``keeper`` is not yet published."""
        if self._joins is None or id(keeper) in self._published:
            return False
        key = (id(keeper), id(piece))
        if key not in self._joins_asked:
            self._joins_asked[key] = self._joins(keeper, piece)
        return self._joins_asked[key]


def _connected(pieces: Sequence[_Piece[Any]], start: int) -> list[int]:
    """The indices of the pieces ``start`` reaches over neighbours, ascending."""
    group, todo = {start}, [start]
    while todo:
        for b in pieces[todo.pop()].neighbours:
            if b not in group:
                group.add(b)
                todo.append(b)
    return sorted(group)


def _better(a: _Piece[Any], b: _Piece[Any]) -> bool:
    """Whether ``a`` is the better of two overlapping fits: fitness, then ROI points, then
    the lower instance id (a total order, so exactly one of two is kept)."""
    return (a.score, a.points, -a.detection.instance_id) > \
        (b.score, b.points, -b.detection.instance_id)


def fragment_filter(jobs: Sequence[PartJob], publish: Callable[[Detection], None],
                    database: TemplateDatabase, overlap: float,
                    explains: Callable[[Detection, Detection], bool] | None = None,
                    joins: Callable[[Detection, Detection], bool] | None = None,
                    touching: Callable[[Detection, Detection], bool] | None = None,
                    band: Callable[[Detection, Detection], bool] | None = None,
                    same: Callable[[Detection, Detection], bool] | None = None
                    ) -> FragmentFilter[Detection]:
    """The :class:`FragmentFilter` of one frame's parts (``PartJob`` items): ROI centroids in
    the world (camera frame without a table frame), first-class diameters from ``database``."""
    pieces = []
    for job in jobs:
        centroid = job.points.mean(axis=0)
        frame = 'world' if job.T_world_camera is not None else job.detection.view
        if job.T_world_camera is not None:
            centroid = transform_points(job.T_world_camera, centroid[None])[0]
        pieces.append((job.detection, centroid, frame, len(job.points),
                       database[job.candidates[0]].diameter_m))
    return FragmentFilter(pieces, publish, overlap=overlap, explains=explains, joins=joins,
                          touching=touching, band=band, same=same)
