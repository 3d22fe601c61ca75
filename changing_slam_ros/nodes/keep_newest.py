"""Bounded per-stamp dicts: drop the oldest entries (insertion order) beyond a limit."""

from __future__ import annotations

from typing import Any


def keep_newest(by_stamp: dict[int, Any], n: int) -> None:
    """Drop the oldest entries (insertion order) of a per-stamp dict until at most `n` are left."""
    while len(by_stamp) > n:
        del by_stamp[next(iter(by_stamp))]
