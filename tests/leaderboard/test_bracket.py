"""leaderboard.bracket_draw: seeding, byes, running brackets to a champion, JSON storage (pure)."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable

import pytest

from leaderboard.bracket_draw import (
    Bracket,
    Match,
    bracket_size,
    champion,
    is_finished,
    next_matches,
    record_winner,
    seed_bracket,
    seed_order,
)

Pick = Callable[[Match], int]


def lower_seed(match: Match) -> int:
    return min(match.top, match.bottom)


def higher_seed(match: Match) -> int:
    return max(match.top, match.bottom)


def run(bracket: Bracket, pick: Pick) -> tuple[Bracket, list[Match]]:
    """Race every ready match, first ready first, until the bracket has a champion."""
    raced = []
    while not is_finished(bracket):
        match = next_matches(bracket)[0]
        raced.append(match)
        bracket = record_winner(bracket, match.round, match.index, pick(match))
    assert next_matches(bracket) == []
    return bracket, raced


def first_round(bracket: Bracket) -> tuple[list[tuple[int, int]], list[int]]:
    """(the races of round 1 as (top, bottom), the seeds through on a bye)."""
    races = [(m.top, m.bottom) for m in bracket.rounds[0] if not m.bye]
    byes = [m.winner for m in bracket.rounds[0] if m.bye]
    return races, byes


SEED_ORDERS = {
    2: (1, 2),
    4: (1, 4, 2, 3),
    8: (1, 8, 4, 5, 2, 7, 3, 6),
    16: (1, 16, 8, 9, 4, 13, 5, 12, 2, 15, 7, 10, 3, 14, 6, 11),
}


@pytest.mark.parametrize("size", SEED_ORDERS)
def test_seed_order_is_the_classic_one(size):
    assert seed_order(size) == SEED_ORDERS[size]


def test_seed_order_of_32_extends_that_of_16():
    order = seed_order(32)
    assert sorted(order) == list(range(1, 33))
    assert order[::2] == SEED_ORDERS[16]
    assert order[:8] == (1, 32, 16, 17, 8, 25, 9, 24)


@pytest.mark.parametrize("size", [2, 4, 8, 16, 32])
def test_round_one_pairs_each_seed_with_its_mirror(size):
    order = seed_order(size)
    pairs = list(zip(order[::2], order[1::2], strict=True))
    assert pairs[0] == (1, size)
    assert all(top + bottom == size + 1 and top < bottom for top, bottom in pairs)


@pytest.mark.parametrize("size", [4, 8, 16, 32])
def test_top_seeds_meet_as_late_as_possible(size):
    """The best 2**k seeds sit in 2**k different blocks of the bracket, so seeds 1 and 2 meet
    only in the final, seeds 1-4 only in the semi-finals, and so on."""
    order = seed_order(size)
    k = 1
    while 2**k <= size:
        block = size // 2**k
        blocks = [order.index(seed) // block for seed in range(1, 2**k + 1)]
        assert sorted(blocks) == list(range(2**k))
        k += 1


def test_seeds_one_and_two_meet_in_the_final():
    bracket, raced = run(seed_bracket(16), lower_seed)
    final = bracket.rounds[-1][0]
    assert (final.top, final.bottom) == (1, 2)
    assert all({m.top, m.bottom} != {1, 2} for m in raced[:-1])
    semis = bracket.rounds[-2]
    assert sorted((m.top, m.bottom) for m in semis) == [(1, 4), (2, 3)]


def test_three_entries_seed_one_waits_in_the_final():
    bracket = seed_bracket(3)
    assert (bracket.size, bracket.entries) == (4, 3)
    assert bracket.rounds[0] == (
        Match(1, 0, 1, None, 1, True),
        Match(1, 1, 2, 3, None, False),
    )
    assert bracket.rounds[1] == (Match(2, 0, 1, None, None, False),)
    assert next_matches(bracket) == [bracket.rounds[0][1]]


def test_five_entries():
    bracket = seed_bracket(5)
    assert bracket.size == 8
    assert first_round(bracket) == ([(4, 5)], [1, 2, 3])
    assert [(m.top, m.bottom) for m in bracket.rounds[1]] == [(1, None), (2, 3)]
    assert [(m.top, m.bottom) for m in next_matches(bracket)] == [(4, 5), (2, 3)]


def test_eight_entries_have_no_byes():
    bracket = seed_bracket(8)
    assert first_round(bracket) == ([(1, 8), (4, 5), (2, 7), (3, 6)], [])
    assert all(m.top is None and m.bottom is None for r in bracket.rounds[1:] for m in r)
    assert next_matches(bracket) == list(bracket.rounds[0])


def test_thirteen_entries():
    bracket = seed_bracket(13)
    assert bracket.size == 16
    races, byes = first_round(bracket)
    assert races == [(8, 9), (4, 13), (5, 12), (7, 10), (6, 11)]
    assert sorted(byes) == [1, 2, 3]
    assert [(m.top, m.bottom) for m in bracket.rounds[1]] == [
        (1, None),
        (None, None),
        (2, None),
        (3, None),
    ]


@pytest.mark.parametrize("entries", range(2, 33))
def test_byes_go_only_to_the_top_seeds(entries):
    bracket = seed_bracket(entries)
    races, byes = first_round(bracket)
    assert sorted(byes) == list(range(1, bracket.size - entries + 1))
    assert all(m.bottom is None and m.winner == m.top for m in bracket.rounds[0] if m.bye)
    raced = sorted(seed for pair in races for seed in pair)
    assert raced == list(range(bracket.size - entries + 1, entries + 1))


def test_more_entries_than_the_cap_seed_only_the_top_ones():
    bracket = seed_bracket(40, cap=16)
    assert (bracket.size, bracket.entries) == (16, 16)
    assert first_round(bracket)[1] == []
    assert max(seed for m in bracket.rounds[0] for seed in (m.top, m.bottom)) == 16


@pytest.mark.parametrize("entries", [3, 5, 8, 13])
def test_always_the_lower_seed_wins(entries):
    bracket, _ = run(seed_bracket(entries), lower_seed)
    assert champion(bracket) == 1


@pytest.mark.parametrize("entries", [3, 5, 8, 13])
def test_always_the_higher_seed_number_wins(entries):
    bracket, _ = run(seed_bracket(entries), higher_seed)
    assert champion(bracket) == entries


@pytest.mark.parametrize(("entries", "cap"), [(n, 32) for n in range(2, 33)] + [(40, 8)])
@pytest.mark.parametrize("pick", [lower_seed, higher_seed])
def test_a_champion_takes_one_race_fewer_than_there_are_entries(entries, cap, pick):
    bracket, raced = run(seed_bracket(entries, cap), pick)
    assert len(raced) == min(entries, cap) - 1
    decided = [m for r in bracket.rounds for m in r if not m.bye and m.winner is not None]
    assert len(decided) == len(raced)


def test_record_winner_moves_the_winner_on():
    bracket = seed_bracket(8)
    bracket = record_winner(bracket, 1, 2, 7)
    assert bracket.rounds[1][1] == Match(2, 1, 7, None, None, False)
    bracket = record_winner(bracket, 1, 3, 3)
    assert bracket.rounds[1][1] == Match(2, 1, 7, 3, None, False)
    assert bracket.rounds[0][2].winner == 7


def test_record_winner_leaves_the_old_bracket_alone():
    before = seed_bracket(4)
    after = record_winner(before, 1, 0, 4)
    assert before == seed_bracket(4)
    assert after.rounds[1][0].top == 4


@pytest.mark.parametrize(
    ("round_", "index", "winner", "message"),
    [
        (1, 1, 4, "not racing"),
        (1, 1, None, "not racing"),
        (2, 0, 1, "not ready"),
        (1, 0, 1, "is a bye"),
        (3, 0, 1, "no match 0 in round 3"),
        (1, 2, 2, "no match 2 in round 1"),
        (0, 0, 1, "no match 0 in round 0"),
    ],
)
def test_record_winner_errors(round_, index, winner, message):
    with pytest.raises(ValueError, match=message):
        record_winner(seed_bracket(3), round_, index, winner)


def test_record_winner_twice_is_an_error():
    bracket = record_winner(seed_bracket(3), 1, 1, 3)
    with pytest.raises(ValueError, match="already has a winner: seed 3"):
        record_winner(bracket, 1, 1, 2)


def test_a_finished_bracket_takes_no_more_winners():
    bracket, _ = run(seed_bracket(4), lower_seed)
    assert is_finished(bracket)
    with pytest.raises(ValueError, match="already has a winner"):
        record_winner(bracket, 2, 0, 2)


@pytest.mark.parametrize("entries", [2, 3, 5, 8, 13, 32])
def test_to_dict_round_trips_through_json_at_every_step(entries):
    bracket = seed_bracket(entries)
    steps = [bracket]
    while not is_finished(bracket):
        match = next_matches(bracket)[-1]
        bracket = record_winner(bracket, match.round, match.index, higher_seed(match))
        steps.append(bracket)
    for step in steps:
        stored = json.loads(json.dumps(step.to_dict()))
        assert stored == step.to_dict()
        assert Bracket.from_dict(stored) == step


def test_to_dict_is_plain_data():
    assert seed_bracket(3).to_dict() == {
        "size": 4,
        "entries": 3,
        "rounds": [
            [
                {"round": 1, "index": 0, "top": 1, "bottom": None, "winner": 1, "bye": True},
                {"round": 1, "index": 1, "top": 2, "bottom": 3, "winner": None, "bye": False},
            ],
            [{"round": 2, "index": 0, "top": 1, "bottom": None, "winner": None, "bye": False}],
        ],
    }


def broken(change: Callable[[dict], object]) -> dict:
    """seed_bracket(5) after one record_winner, as a dict, with ``change`` made to it."""
    data = copy.deepcopy(record_winner(seed_bracket(5), 1, 1, 4).to_dict())
    change(data)
    return data


MALFORMED = {
    "extra key": (lambda d: d.update(extra=1), "a bracket is a dict"),
    "size a string": (lambda d: d.update(size="8"), "size must be one of"),
    "size not a power of two": (lambda d: d.update(size=6), "size must be one of"),
    "size too big": (lambda d: d.update(size=64), "size must be one of"),
    "entries a bool": (lambda d: d.update(entries=True), "entries must be an int"),
    "entries too few for the size": (lambda d: d.update(entries=4), "holds 5-8 entries"),
    "entries too many for the size": (lambda d: d.update(entries=9), "holds 5-8 entries"),
    "rounds not a list": (lambda d: d.update(rounds="x"), "rounds of \\[4, 2, 1\\] matches"),
    "a round missing": (lambda d: d["rounds"].pop(), "rounds of \\[4, 2, 1\\] matches"),
    "a round too short": (lambda d: d["rounds"][1].pop(), "rounds of \\[4, 2, 1\\] matches"),
    "a match not a dict": (
        lambda d: d["rounds"][0].__setitem__(0, [1, 0, 1, None, 1, True]),
        "a match is a dict",
    ),
    "a match key missing": (lambda d: d["rounds"][0][0].pop("bye"), "a match is a dict"),
    "a seed a float": (lambda d: d["rounds"][0][1].update(top=4.0), "ints or None"),
    "a seed a string": (lambda d: d["rounds"][0][1].update(winner="4"), "ints or None"),
    "bye an int": (lambda d: d["rounds"][0][0].update(bye=1), "bye is a bool"),
    "round numbers swapped": (lambda d: d["rounds"][0][0].update(round=2), "does not follow"),
    "a seed changed": (lambda d: d["rounds"][0][1].update(bottom=6), "does not follow"),
    "a winner not moved on": (lambda d: d["rounds"][1][0].update(bottom=None), "does not follow"),
    "a winner not racing": (lambda d: d["rounds"][0][1].update(winner=7), "seed 7 is not racing"),
    "a bye dropped": (
        lambda d: d["rounds"][0][0].update(bye=False, winner=None, bottom=8),
        "does not follow",
    ),
    "a winner before the match was ready": (
        lambda d: d["rounds"][2][0].update(winner=1),
        "not ready",
    ),
}


@pytest.mark.parametrize(("change", "message"), MALFORMED.values(), ids=MALFORMED.keys())
def test_from_dict_rejects_malformed_input(change, message):
    with pytest.raises(ValueError, match=message):
        Bracket.from_dict(broken(change))


def test_from_dict_rejects_a_non_dict():
    for data in (None, [], "bracket", 8):
        with pytest.raises(ValueError, match="a bracket is a dict"):
            Bracket.from_dict(data)


@pytest.mark.parametrize(
    ("entries", "size"),
    [(2, 2), (3, 4), (4, 4), (5, 8), (8, 8), (9, 16), (16, 16), (17, 32), (32, 32)]
    + [(n, 32) for n in range(33, 41)],
)
def test_bracket_size(entries, size):
    assert bracket_size(entries) == size


def test_bracket_size_for_2_to_40_is_the_smallest_power_of_two_that_fits():
    for entries in range(2, 41):
        size = bracket_size(entries)
        assert size in (2, 4, 8, 16, 32)
        assert size >= min(entries, 32) > size // 2


@pytest.mark.parametrize(("entries", "cap", "size"), [(40, 4, 4), (5, 4, 4), (9, 8, 8), (3, 8, 4)])
def test_bracket_size_is_capped(entries, cap, size):
    assert bracket_size(entries, cap) == size


@pytest.mark.parametrize("cap", [0, 2, 5, 12, 64, -8])
def test_bracket_size_rejects_other_caps(cap):
    with pytest.raises(ValueError, match=r"cap must be one of \(4, 8, 16, 32\)"):
        bracket_size(8, cap)


@pytest.mark.parametrize("entries", [0, 1, -3])
def test_bracket_size_needs_two_entries(entries):
    with pytest.raises(ValueError, match="a bracket needs at least 2 entries"):
        bracket_size(entries)
    with pytest.raises(ValueError, match="at least 2 entries"):
        seed_bracket(entries)
