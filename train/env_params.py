"""Environment parameters in a run configuration: the common key ``env`` holds values for fields of the scenario's
``params`` pytree (``env.default_params``: reward weights, costs, speed ranges, initial speeds, durations).

On the command line a field is named ``env.<field>``: ``--set env.collision_reward=-2`` sets one value,
``--sweep env.collision_reward=[-1,-2]`` sweeps it (train/sweep.py). Only real-valued fields can be given: a
number, or an array of numbers with the shape of the default (so a value never changes the program's shapes).
Integer and true/false fields (lane indices, flags), fields without a default and nested groups (the traffic
drivers' ``idm``) are refused with a ValueError naming them and the fields that can be given.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from train.config import ENV_PREFIX as PREFIX

__all__ = ["PREFIX", "is_env_key", "field_of", "real_fields", "check_fields", "with_values"]

def is_env_key(key: str) -> bool:
    """``env.<field>``: a key naming an environment parameter."""
    return key.startswith(PREFIX)


def field_of(key: str) -> str:
    """``env.collision_reward`` -> ``collision_reward``."""
    return key[len(PREFIX):]


def _real_shape(value: Any) -> tuple | None:
    """The shape of a real-valued parameter (a float, or a float array or tuple of floats), else None."""
    if value is None or dataclasses.is_dataclass(value) or isinstance(value, (bool, int, np.bool_, np.integer)):
        return None
    if isinstance(value, (float, np.floating)):
        return ()
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        return None
    return arr.shape if arr.dtype.kind == "f" and arr.size else None


def real_fields(params) -> dict[str, tuple]:
    """``{field: shape}`` of every real-valued field of ``params``, in declaration order."""
    out = {}
    for f in dataclasses.fields(params):
        shape = _real_shape(getattr(params, f.name))
        if shape is not None:
            out[f.name] = shape
    return out


def check_fields(scenario: str, params, names, what: str = "set") -> None:
    """ValueError naming every field of ``names`` that is not a real-valued field of ``params`` (listing those
    that are, as ``env.<field>``)."""
    allowed = real_fields(params)
    bad = [n for n in names if n not in allowed]
    if bad:
        fields = {f.name for f in dataclasses.fields(params)}
        unknown = [n for n in bad if n not in fields]
        why = (f"{', '.join(PREFIX + n for n in unknown)} {'is' if len(unknown) == 1 else 'are'} not a parameter of "
               f"{scenario}" if unknown else "")
        fixed = [n for n in bad if n in fields]
        if fixed:
            verb = "is" if len(fixed) == 1 else "are"
            why += ("; " if why else "") + (f"{', '.join(PREFIX + n for n in fixed)} {verb} not real-valued (an "
                                            f"integer, a flag, unset or a group of parameters)")
        raise ValueError(f"cannot {what} {', '.join(PREFIX + n for n in bad)}: {why}. Real-valued environment "
                         f"parameters of {scenario}: {', '.join(PREFIX + n for n in allowed)}")


def with_values(scenario: str, params, values: dict) -> Any:
    """``params`` with ``values`` (field -> number or nested list) in place of the defaults: each a real-valued
    field, given with the default's shape and finite; ranges as :func:`envs_jax.registry.check_ranges`."""
    if not values:
        return params
    from envs_jax.registry import check_ranges

    check_fields(scenario, params, list(values))
    allowed = real_fields(params)
    out = {}
    for name, v in values.items():
        arr = np.asarray(v, dtype=np.float64)
        if arr.shape != allowed[name]:
            want = "a number" if allowed[name] == () else f"an array of shape {list(allowed[name])}"
            raise ValueError(f"{PREFIX}{name} of {scenario} must be {want} (the default's shape), got {v!r}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{PREFIX}{name} of {scenario} must be finite, got {v!r}")
        default = getattr(params, name)
        out[name] = float(arr) if allowed[name] == () else (
            tuple(arr.tolist()) if isinstance(default, tuple) else arr)
    check_ranges(scenario, params, out)
    return params.replace(**out)
