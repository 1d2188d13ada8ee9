"""The draw of a head-to-head event's single-elimination bracket: pure dataclasses (no Django,
no I/O). The event's bracket itself (seeding it, its races, its results) is
:mod:`leaderboard.bracket`.

The 2020 AWS DeepRacer League ran head-to-head races this way: a qualifying round ranks the
racers, then the top 4, 8, 16 or 32 qualifiers are seeded into a bracket of one-against-one
races, seed 1 against the last seed, in the classic order where seeds 1 and 2 can meet only in
the final, seeds 1-4 only in the semi-finals, and so on. With fewer qualifiers than the bracket
has places, the missing (highest) seeds are byes: the top seeds they would have met go through
to round 2 without a race.

Seeds are 1-based qualifying ranks; the caller maps them to racers. Rounds are 1-based, match
indexes 0-based within a round; the winner of match ``i`` goes to match ``i // 2`` of the next
round, on top from an even ``i`` and at the bottom from an odd one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

SIZES = (2, 4, 8, 16, 32)
"""Bracket sizes (places, including byes)."""
CAPS = (4, 8, 16, 32)
"""How many qualifiers an event may take into its bracket."""

Slot = int | None
"""One side of a match: a seed, or None for a bye or a winner not decided yet."""


@dataclass(frozen=True)
class Match:
    round: int
    index: int
    top: Slot
    bottom: Slot
    winner: Slot
    bye: bool

    @property
    def ready(self) -> bool:
        """Both racers known, not a bye, no winner yet: it can be raced."""
        return None not in (self.top, self.bottom) and not self.bye and self.winner is None


@dataclass(frozen=True)
class Bracket:
    """``size`` places (one of SIZES) for ``entries`` seeds, ``size // 2 < entries <= size``;
    ``rounds[0]`` holds ``size // 2`` matches, each later round half as many, the last the final."""

    size: int
    entries: int
    rounds: tuple[tuple[Match, ...], ...]

    def to_dict(self) -> dict[str, Any]:
        """Plain ints, bools, None, lists and dicts, for JSON."""
        return {
            "size": self.size,
            "entries": self.entries,
            "rounds": [[_match_dict(m) for m in matches] for matches in self.rounds],
        }

    @classmethod
    def from_dict(cls, data: Any) -> Bracket:
        """The inverse of :meth:`to_dict`; ValueError unless ``data`` is a bracket that
        :func:`seed_bracket` and :func:`record_winner` could have made."""
        if not isinstance(data, dict) or set(data) != {"size", "entries", "rounds"}:
            raise ValueError("a bracket is a dict with exactly size, entries and rounds")
        size, entries, rounds = data["size"], data["entries"], data["rounds"]
        if not _is_int(size) or size not in SIZES:
            raise ValueError(f"bracket size must be one of {SIZES}, not {size!r}")
        if not _is_int(entries):
            raise ValueError(f"bracket entries must be an int, not {entries!r}")
        if not size // 2 < entries <= size:
            raise ValueError(f"a bracket of {size} places holds {size // 2 + 1}-{size} entries")
        lengths = [size >> r for r in range(1, size.bit_length())]
        if not isinstance(rounds, list) or [_len(r) for r in rounds] != lengths:
            raise ValueError(f"a bracket of {size} places has rounds of {lengths} matches")
        parsed = cls(size, entries, tuple(tuple(_parse_match(m) for m in r) for r in rounds))
        # Replay the recorded winners on a fresh seeding: only a reachable state compares equal.
        rebuilt = seed_bracket(entries)
        for match in (m for r in parsed.rounds for m in r if not m.bye):
            if match.winner is not None:
                rebuilt = record_winner(rebuilt, match.round, match.index, match.winner)
        if rebuilt != parsed:
            raise ValueError("the bracket does not follow from its seeding and recorded winners")
        return parsed


def bracket_size(entries: int, cap: int = 32) -> int:
    """Places in the bracket for ``entries`` qualifiers: the smallest of SIZES that holds them,
    at most ``cap`` (one of CAPS; only the top ``cap`` qualify). ValueError on a bad cap or
    fewer than 2 entries."""
    if cap not in CAPS:
        raise ValueError(f"the bracket cap must be one of {CAPS}, not {cap!r}")
    if entries < 2:
        raise ValueError("a bracket needs at least 2 entries")
    return next(s for s in SIZES if s >= min(entries, cap))


def seed_order(size: int) -> tuple[int, ...]:
    """Seeds in bracket order, paired off two by two for round 1: ``(1, 4, 2, 3)`` for 4."""
    if size not in SIZES:
        raise ValueError(f"bracket size must be one of {SIZES}, not {size!r}")
    order = (1, 2)
    while len(order) < size:
        n = 2 * len(order)
        order = tuple(x for s in order for x in (s, n + 1 - s))
    return order


def seed_bracket(entries: int, cap: int = 32) -> Bracket:
    """The bracket of the top ``min(entries, cap)`` qualifiers, byes already decided."""
    size = bracket_size(entries, cap)
    entries = min(entries, cap)
    order = seed_order(size)
    first = []
    for i in range(size // 2):
        top, bottom = order[2 * i], order[2 * i + 1]
        bye = bottom > entries  # the top seed of a pair is always the lower number
        first.append(Match(1, i, top, None if bye else bottom, top if bye else None, bye))
    rounds = [tuple(first)]
    while len(rounds[-1]) > 1:
        feeders = rounds[-1]
        r = len(rounds) + 1
        rounds.append(
            tuple(
                Match(r, i, feeders[2 * i].winner, feeders[2 * i + 1].winner, None, False)
                for i in range(len(feeders) // 2)
            )
        )
    return Bracket(size, entries, tuple(rounds))


def record_winner(bracket: Bracket, round: int, index: int, winner: int) -> Bracket:
    """A copy of ``bracket`` with ``winner`` recorded for the match and moved on to the next
    round. ValueError if there is no such match, it is a bye, it already has a winner, a side
    is still undecided, or ``winner`` is not one of its two racers."""
    if not (1 <= round <= len(bracket.rounds) and 0 <= index < len(bracket.rounds[round - 1])):
        raise ValueError(f"there is no match {index} in round {round}")
    match = bracket.rounds[round - 1][index]
    where = f"match {index} of round {round}"
    if match.bye:
        raise ValueError(f"{where} is a bye: seed {match.top} is through without a race")
    if match.winner is not None:
        raise ValueError(f"{where} already has a winner: seed {match.winner}")
    if match.top is None or match.bottom is None:
        raise ValueError(f"{where} is not ready: a side is still undecided")
    if winner not in (match.top, match.bottom):
        raise ValueError(f"seed {winner!r} is not racing in {where} ({match.top} v {match.bottom})")
    rounds = [list(r) for r in bracket.rounds]
    rounds[round - 1][index] = replace(match, winner=winner)
    if round < len(rounds):
        after = rounds[round][index // 2]
        side = "top" if index % 2 == 0 else "bottom"
        rounds[round][index // 2] = replace(after, **{side: winner})
    return replace(bracket, rounds=tuple(tuple(r) for r in rounds))


def next_matches(bracket: Bracket) -> list[Match]:
    """Every match that can be raced now, by round then index."""
    return [m for r in bracket.rounds for m in r if m.ready]


def champion(bracket: Bracket) -> int | None:
    """The final's winner, or None while it is undecided."""
    return bracket.rounds[-1][0].winner


def is_finished(bracket: Bracket) -> bool:
    return champion(bracket) is not None


def _is_int(value: Any) -> bool:
    return type(value) is int  # bool is an int subclass, and True is no seed


def _len(value: Any) -> int | None:
    return len(value) if isinstance(value, list) else None


_FIELDS = ("round", "index", "top", "bottom", "winner", "bye")


def _match_dict(match: Match) -> dict[str, Any]:
    return {name: getattr(match, name) for name in _FIELDS}


def _parse_match(data: Any) -> Match:
    if not isinstance(data, dict) or set(data) != set(_FIELDS):
        raise ValueError(f"a match is a dict with exactly {', '.join(_FIELDS)}")
    if not all(_is_int(data[k]) for k in ("round", "index")):
        raise ValueError("a match's round and index are ints")
    if not all(data[k] is None or _is_int(data[k]) for k in ("top", "bottom", "winner")):
        raise ValueError("a match's top, bottom and winner are ints or None")
    if type(data["bye"]) is not bool:
        raise ValueError("a match's bye is a bool")
    return Match(**data)
