"""Pacing a stream of time-stamped items at a multiple of wall-clock speed."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


def paced(items: Iterable[T], time_of: Callable[[T], float], rate: float | None = 1.0,
          *, origin_s: float | None = None, clock: Callable[[], float] = time.monotonic,
          sleep: Callable[[float], None] = time.sleep) -> Iterator[T]:
    """Yield each item once the wall clock has reached its time.

    ``time_of(item)`` is the item's time [s] on the stream's own clock; the wall clock
    starts when the first item arrives, at stream time ``origin_s`` (default: the first
    item's time). ``rate`` is the multiple of real time (1 = real time, 2 = twice as
    fast); ``None`` yields at once (no pacing). An item that is already late is yielded
    without sleeping, so a slow consumer never accumulates extra delay.
    """
    if rate is not None and rate <= 0:
        raise ValueError(f"pacing rate must be positive, got {rate}")
    start: float | None = None
    origin = 0.0 if origin_s is None else origin_s
    for item in items:
        if rate is not None:
            t = float(time_of(item))
            if start is None:
                start = clock()
                origin = t if origin_s is None else origin
            delay = start + (t - origin) / rate - clock()
            if delay > 0:
                sleep(delay)
        yield item
