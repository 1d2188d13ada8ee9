"""The errors services and selectors raise: each carries a message a user can act on; and the
object store's (:class:`StoreError`, :class:`ObjectNotFound`), which the web catches to answer
"storage unavailable, try again"."""

from __future__ import annotations

from training.sandbox import RewardError
from training.storage import ObjectNotFound, StoreError

__all__ = ["ObjectNotFound", "RewardRejected", "ServiceError", "StoreError"]


class ServiceError(Exception):
    """A request we refuse; ``field`` names the form field to show it on, when there is one."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.field = field

    @property
    def sentence(self) -> str:
        """The message as a sentence for a page: capitalised."""
        return self.message[:1].upper() + self.message[1:]


class RewardRejected(ServiceError):
    """The reward function failed validation; ``errors`` are DeepRacer-style error dicts."""

    def __init__(self, errors: list[RewardError]) -> None:
        first = errors[0]
        where = f" (line {first.line})" if first.line else ""
        super().__init__(f"{first.message}{where}", field="reward_function")
        self.errors = [e.to_dict() for e in errors]
