"""Checks for values a sandbox sent: every message is checked before use.

The protocol (:mod:`training.sandbox.protocol`) guarantees only well-formed JSON and arrays
of plain dtypes; a child running user code can still send any such value in any place. These
helpers accept exactly what the caller expects (kind, index range, finite bounded rewards,
array shape and dtype) and raise :class:`Malformed` for anything else, which callers turn
into their "sent malformed data" error: never an exception the trainer does not expect.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from training.sandbox.guard import MAX_REWARD

#: What the user reads when a sandbox's message fails a check.
MALFORMED = "The reward function's sandbox sent malformed data."
MAX_TEXT = 2000


class Malformed(ValueError):
    """A value from a sandbox is not what was expected; the message names what and where."""


def mapping(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise Malformed(f"{where}: expected an object")
    return value


def index(value: Any, size: int, where: str) -> int:
    """An int in ``range(size)`` (not a bool, not a float)."""
    if type(value) is not int or not 0 <= value < size:
        raise Malformed(f"{where}: index out of range")
    return value


def number(value: Any, where: str, *, bound: float = MAX_REWARD) -> float:
    """A finite int or float (not a bool) within ``[-bound, bound]``."""
    if type(value) not in (int, float):
        raise Malformed(f"{where}: expected a number")
    try:
        result = float(value)
    except OverflowError:
        raise Malformed(f"{where}: number out of range") from None
    if not math.isfinite(result) or abs(result) > bound:
        raise Malformed(f"{where}: number out of range")
    return result


def integer(value: Any, where: str, *, low: int = 0, high: int = 2**53) -> int:
    if type(value) is not int or not low <= value <= high:
        raise Malformed(f"{where}: expected an integer in [{low}, {high}]")
    return value


def text(value: Any, where: str, *, limit: int = MAX_TEXT) -> str:
    if not isinstance(value, str) or len(value) > limit:
        raise Malformed(f"{where}: expected text of at most {limit} characters")
    return value


def array(value: Any, where: str, *, dtype: Any, shape: tuple[int, ...]) -> np.ndarray:
    """An ndarray of exactly ``dtype`` and ``shape``."""
    if not isinstance(value, np.ndarray) or value.dtype != np.dtype(dtype) or value.shape != shape:
        raise Malformed(f"{where}: expected a {np.dtype(dtype).name} array of shape {shape}")
    return value


def rewards(value: Any, where: str, *, size: int) -> np.ndarray:
    """A float32 vector of ``size`` finite rewards within the guard's bounds."""
    arr = array(value, where, dtype=np.float32, shape=(size,))
    if not np.all(np.isfinite(arr)) or np.any(np.abs(arr) > MAX_REWARD):
        raise Malformed(f"{where}: rewards must be finite and within +-{MAX_REWARD:g}")
    return arr


def scalars(value: Any, where: str, *, limit: int = 64) -> list[Any]:
    """A short list of JSON scalars (None, bool, finite numbers, short text)."""
    if not isinstance(value, list) or len(value) > limit:
        raise Malformed(f"{where}: expected a list of at most {limit} values")
    for item in value:
        if item is None or type(item) is bool:
            continue
        if isinstance(item, str):
            text(item, where, limit=256)
        else:
            number(item, where, bound=1e15)
    return value
