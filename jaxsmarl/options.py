"""Hyper-parameters as config dataclass fields that carry their own help line and validation rule.

An algorithm's config dataclass is the one source of its defaults: a field made with :func:`option` holds the
default, one line of help and the rule that checks a user's value; :func:`option_table` reads them back, which is
how the command line (:mod:`train.config`) registers the algorithm's keys and writes ``--help``. Fields made with
plain ``dataclasses.field`` (sizes taken from the environment, a variant's structure) are not user options.

A rule is a callable ``rule(key, value) -> normalised value`` raising ``ValueError`` that names the key and what
is allowed (:class:`PerAgent` also takes the number of agents). Nothing here imports JAX, so a command line can
answer ``--help`` and reject bad options before JAX starts.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

__all__ = ["TERMINAL_MASKS", "Bool", "Choice", "Int", "Num", "PerAgent", "Sizes", "option", "option_table"]

# The off-policy learners' `terminal_mask` choices (jaxsmarl.bootstrap defines each rule).
TERMINAL_MASKS = ("sample", "batch_mean")


@dataclasses.dataclass(frozen=True)
class Int:
    lo: int = 0

    def __call__(self, key: str, v: Any) -> int:
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if not isinstance(v, int) or isinstance(v, bool) or v < self.lo:
            raise ValueError(f"'{key}' must be an integer >= {self.lo}, got {v!r}")
        return v


@dataclasses.dataclass(frozen=True)
class Num:
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    hint: str = ""  # appended to the error message

    def check(self, key: str, v: Any) -> float:
        hint = f" ({self.hint})" if self.hint else ""
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            raise ValueError(f"'{key}' must be a finite number, got {v!r}{hint}")
        if (v <= self.lo if self.lo_open else v < self.lo) or (v >= self.hi if self.hi_open else v > self.hi):
            raise ValueError(f"'{key}' must lie in {'(' if self.lo_open else '['}{self.lo}, {self.hi}"
                             f"{')' if self.hi_open else ']'}, got {v}{hint}")
        return float(v)

    __call__ = check


@dataclasses.dataclass(frozen=True)
class Choice:
    values: tuple

    def __call__(self, key: str, v: Any) -> Any:
        if v not in self.values:
            raise ValueError(f"'{key}' must be one of {', '.join(map(str, self.values))}, got {v!r}")
        return v


@dataclasses.dataclass(frozen=True)
class Bool:
    def __call__(self, key: str, v: Any) -> bool:
        if not isinstance(v, bool):
            raise ValueError(f"'{key}' must be true or false, got {v!r}")
        return v


@dataclasses.dataclass(frozen=True)
class PerAgent:
    """A number per agent (``[leader, follower]`` for two); a single number, or a list of equal numbers such as the
    two-agent defaults, sets every agent's. ``n``: the number of agents (the config's ``agents``)."""

    num: Num = Num()

    def __call__(self, key: str, v: Any, n: int = 2) -> list[float]:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            v = [v] * n
        numbers = isinstance(v, (list, tuple)) and len(v) > 0 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        if numbers and len(v) != n and all(x == v[0] for x in v):
            v = [v[0]] * n
        if not numbers or len(v) != n:
            what = "two numbers [leader, follower]" if n == 2 else f"{n} numbers, one per agent"
            raise ValueError(f"'{key}' must be a number or a list of {what}, got {v!r}")
        return [self.num.check(key, x) for x in v]


@dataclasses.dataclass(frozen=True)
class Sizes:
    """A non-empty list of positive integers (hidden layer widths)."""

    def __call__(self, key: str, v: Any) -> list[int]:
        if not isinstance(v, (list, tuple)) or len(v) == 0 or not all(
                isinstance(h, int) and not isinstance(h, bool) and h > 0 for h in v):
            raise ValueError(f"'{key}' must be a non-empty list of positive integers, got {v!r}")
        return list(v)


def option(default: Any, help: str, rule: Callable | None = None, only: str | None = None):
    """A dataclass field that is a user option: ``default``, one ``help`` line, the ``rule`` checking a value
    (None: taken as given); ``only``: the name of the variant that alone has this option (e.g. ``"constrained"``),
    None for every variant."""
    if not isinstance(help, str) or not help:
        raise TypeError("option(): help must be a non-empty line of text")
    return dataclasses.field(default=default, metadata={"help": help, "rule": rule, "only": only})


def option_table(cls, variants: tuple[str, ...] = ()) -> tuple[dict, dict, dict]:
    """``(defaults, help, rules)`` of the options of config dataclass ``cls``, in field order: every option whose
    ``only`` is None or one of ``variants``. Tuple defaults are given as lists, as a JSON configuration holds them."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"option_table() takes a config dataclass, got {cls!r}")
    defaults, helps, rules = {}, {}, {}
    for f in dataclasses.fields(cls):
        if "help" not in f.metadata or f.metadata["only"] not in (None, *variants):
            continue
        defaults[f.name] = list(f.default) if isinstance(f.default, tuple) else f.default
        helps[f.name] = f.metadata["help"]
        if f.metadata["rule"] is not None:
            rules[f.name] = f.metadata["rule"]
    return defaults, helps, rules
