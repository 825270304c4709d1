"""Checks of highway-env observation config dicts, shared by the observation types' ``from_config``.

:meth:`envs_jax.kinematic_obs.KinematicsConfig.from_config` and
:meth:`envs_jax.occupancy_grid.OccupancyGridConfig.from_config` read a ``{"type": ..., ...}`` dict with these and
add the checks of their own keys. Every problem raises ``ValueError`` naming ``where``, the key and what is
allowed.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["given_fields", "check_features", "check_flags", "check_features_range"]


def given_fields(config: dict, cls, kind: str, where: str, label: str = "") -> dict:
    """The keys of ``config`` other than ``type``, checked to be fields of dataclass ``cls``; ``type`` must be
    ``kind`` (the default when absent). ``label`` prefixes the word ``key(s)`` in the error message."""
    config = dict(config)
    got = config.pop("type", kind)
    if got != kind:
        raise ValueError(f"{where}: type must be {kind!r}, got {got!r}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(k for k in config if k not in names)
    if unknown:
        raise ValueError(f"{where}: unknown {label}key(s) {unknown}; allowed: {sorted(names) + ['type']}")
    return config


def check_features(out: dict, features, where: str, label: str = "") -> None:
    """``out["features"]``, when given, as a tuple of names from ``features`` (in place)."""
    if "features" not in out:
        return
    feats = out["features"]
    if isinstance(feats, str) or not len(feats) or not all(isinstance(f, str) for f in feats):
        raise ValueError(f"{where}: features must be a non-empty list of names from {list(features)}, got {feats!r}")
    bad = [f for f in feats if f not in features]
    if bad:
        raise ValueError(f"{where}: unknown {label}feature(s) {bad}; allowed: {list(features)}")
    out["features"] = tuple(feats)


def check_flags(out: dict, names, where: str) -> None:
    """Each of ``names`` given in ``out`` is True or False."""
    for k in names:
        if k in out and not isinstance(out[k], (bool, np.bool_)):
            raise ValueError(f"{where}: {k} must be True or False, got {out[k]!r}")


def check_features_range(out: dict, where: str) -> None:
    """``out["features_range"]``, when given and not None, as a tuple of ``(name, (min, max))`` (in place)."""
    if out.get("features_range") is None:
        return
    fr = out["features_range"]
    if not isinstance(fr, dict):
        raise ValueError(f"{where}: features_range must be a dict name -> [min, max], got {fr!r}")
    items = []
    for name, rng in fr.items():
        if (np.shape(rng) != (2,) or not np.all(np.isfinite(np.asarray(rng, float)))
                or float(rng[1]) == float(rng[0])):
            raise ValueError(f"{where}: features_range[{name!r}] must be [min, max] with finite, distinct values, "
                             f"got {rng!r}")
        items.append((str(name), (float(rng[0]), float(rng[1]))))
    out["features_range"] = tuple(items)
