"""The users the service tests share: Alice owns things; Bob must never touch them."""

from __future__ import annotations
