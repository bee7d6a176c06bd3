"""Detection on request: a request waits for the next frames the graph completes after it
arrived, and is answered with their parts, or times out.

Thread-safe: requests wait in their own threads (:meth:`Request.wait`) while another thread
hands in each completed frame (:meth:`RequestBook.on_frame`). With ``frames`` = N > 1 a
request is answered after N frames, with the parts (instance names) present in all N and their
poses in the last: the agreement of N frames.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = ['Request', 'RequestBook']


@dataclass
class Request:
    """One waiting request. ``parts``: the part names to report (empty: all); ``frames``: how
    many frames must agree. Once answered: ``stamp_ns`` (the last frame's source stamp) and
    ``answer`` (items of that frame, filtered)."""

    parts: frozenset[str] = frozenset()
    frames: int = 1
    cancelled: bool = False
    stamp_ns: int | None = None
    answer: list[Any] = field(default_factory=list)
    _seen: list[dict[str, Any]] = field(default_factory=list)
    _done: threading.Event = field(default_factory=threading.Event)

    def wait(self, timeout_s: float) -> bool:
        """Block until answered (True) or ``timeout_s`` passed (False)."""
        return self._done.wait(max(0.0, timeout_s))

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def _take(self, stamp_ns: int, items: Sequence[Any]) -> None:
        self._seen.append({item.instance: item for item in items
                           if not self.parts or item.part in self.parts})
        if len(self._seen) < self.frames:
            return
        last = self._seen[-1]
        agreed = set(last).intersection(*self._seen[:-1]) if self.frames > 1 else set(last)
        self.answer = [item for name, item in last.items() if name in agreed]
        self.stamp_ns = stamp_ns
        self._done.set()


class RequestBook:
    """The open requests and when the last frame came (see the module docstring)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._open: list[Request] = []
        self.frames = 0
        self.last_frame_monotonic: float | None = None

    def open(self, *, parts: Collection[str] = (), frames: int = 1) -> Request:
        """Register a request now: it takes the frames completed from now on.

        Raises:
            ValueError: ``frames`` not in 1..100.
        """
        frames = max(1, int(frames))
        if frames > 100:
            raise ValueError(f'frames must be 1..100, got {frames}')
        request = Request(parts=frozenset(parts), frames=frames)
        with self._lock:
            self._open.append(request)
        return request

    def close(self, request: Request) -> None:
        """Forget a request (answered or timed out)."""
        with self._lock:
            if request in self._open:
                self._open.remove(request)

    def on_frame(self, stamp_ns: int, items: Sequence[Any]) -> int:
        """A completed frame's items (each with ``.instance`` and ``.part``); returns how many
        requests it answered."""
        with self._lock:
            self.frames += 1
            self.last_frame_monotonic = time.monotonic()
            answered = 0
            for request in self._open:
                if not request.done:
                    request._take(stamp_ns, items)
                    answered += request.done
            self._open = [r for r in self._open if not r.done]
        return answered

    def cancel_all(self) -> None:
        """Wake every waiting request unanswered (``cancelled``): the server is stopping."""
        with self._lock:
            for request in self._open:
                request.cancelled = True
                request._done.set()
            self._open = []

    def pending(self) -> int:
        with self._lock:
            return len(self._open)

    def timeout_reason(self, timeout_s: float) -> str:
        """One line for a request that got no answer within ``timeout_s``."""
        last = self.last_frame_monotonic
        since = 'no frame has completed since this node started' if last is None else \
            f'the last frame completed {time.monotonic() - last:.1f} s ago'
        return (f'no frame completed within {timeout_s:.1f} s of the request ({since}): is '
                'the graph ready and a camera (or a replay) running?')
