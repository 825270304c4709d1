"""Hierarchies as data: parsing, validation with the expected form, defaults per K."""

import itertools

import pytest

from jaxsmarl.hierarchy import (
    agent_order,
    chain,
    default_hierarchy,
    flat,
    format_hierarchy,
    is_chain,
    parse_hierarchy,
    validate_hierarchy,
)


@pytest.mark.parametrize("text, k, want", [
    ("0|1|2", 3, ((0,), (1,), (2,))),
    ("0,1|2,3", 4, ((0, 1), (2, 3))),
    ("0,1,2", 3, ((0, 1, 2),)),
    (" 2 | 1,0 ", 3, ((2,), (0, 1))),
    ("0|1", 2, ((0,), (1,))),
    ("chain", 4, ((0,), (1,), (2,), (3,))),
    ("flat", 3, ((0, 1, 2),)),
])
def test_parse(text, k, want):
    assert parse_hierarchy(text, k) == want
    assert validate_hierarchy(text, k) == want
    assert parse_hierarchy(format_hierarchy(want), k) == want


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
def test_every_set_partition_in_every_order_round_trips(k):
    """Brute force: every ordered partition of 0..K-1 into levels is valid and survives string form."""
    agents = list(range(k))
    count = 0
    for labels in itertools.product(range(k), repeat=k):  # level label per agent
        used = sorted(set(labels))
        if used != list(range(len(used))):
            continue
        levels = tuple(tuple(a for a in agents if labels[a] == lv) for lv in used)
        assert validate_hierarchy(levels, k) == levels
        assert parse_hierarchy(format_hierarchy(levels), k) == levels
        assert sorted(agent_order(levels)) == agents
        count += 1
    fubini = {1: 1, 2: 3, 3: 13, 4: 75, 5: 541}  # ordered set partitions (Fubini numbers)
    assert count == fubini[k]


def test_defaults_and_named_forms():
    assert default_hierarchy(2) == ((0,), (1,))  # the paper's leader and follower
    assert default_hierarchy(4) == chain(4)
    assert flat(3) == ((0, 1, 2),)
    assert is_chain(chain(3)) and is_chain(((1,), (0,))) and not is_chain(((0, 1), (2,)))


@pytest.mark.parametrize("levels, k, message", [
    ("0|1", 3, r"misses agent\(s\) \[2\] of 0..2"),
    ("0|1|1", 2, r"repeats agent\(s\) \[1\]"),
    ("0|1|3", 3, r"agent\(s\) \[3\] out of range.*0..2"),
    ("0|-1", 2, r"agent\(s\) \[-1\] out of range"),
    ("0|a", 2, "not understood"),
    ("", 2, "not understood"),
    ("0||1", 2, "not understood"),
    (((0,), ()), 1, "empty level"),
    ([[0, 1.5]], 2, "not a sequence of levels"),
    ([0, 1], 2, "not a sequence of levels"),
])
def test_invalid_hierarchies_show_the_expected_form(levels, k, message):
    with pytest.raises(ValueError, match=message) as err:
        validate_hierarchy(levels, k)
    assert "'0|1|2' (vertical chain)" in str(err.value) and "'0,1|2,3'" in str(err.value)


def test_bad_agent_count():
    with pytest.raises(ValueError, match="number of agents must be an integer >= 1"):
        chain(0)
    with pytest.raises(ValueError, match="number of agents"):
        parse_hierarchy("0", True)
