"""Continuous action model shared by the continuous scenarios (highway-env ``ContinuousAction``).

An agent's action lies in ``[-1, 1]^d`` and is mapped linearly to an
acceleration in [-5, 5] m/s^2 and/or a steering angle in [-pi/4, pi/4] rad
(:func:`envs_jax.vehicle.continuous_action`); the command is held for every
frame of the policy period. Which components the action carries is the
*action mode*, an option of the model, not of the scenario:

* ``"longitudinal"``: ``d = 1``, the action is the acceleration, steering 0
  (intersection's default: each car drives straight along its start heading);
* ``"lateral"``: ``d = 1``, the action is the steering, acceleration 0, so the
  speed stays constant (racetrack's default);
* ``"both"``: ``d = 2``, ``[acceleration, steering]`` in that order.

Every continuous scenario takes ``action_mode`` in its constructor; an
environment from :func:`envs_jax.make` is switched with :func:`with_action_mode`.

Invalid actions: in eager use, a NaN / infinite value or a wrong shape raises
``ValueError`` (``DrivingEnv.check_action``). Inside ``jit`` the values are
not inspectable, so a fixed policy applies instead: NaN is read as 0 and
everything (including +-inf) is clipped to [-1, 1]. The reward terms that use
the action (racetrack's ``|a_i|``) see that sanitised action.
"""

from __future__ import annotations

ACTION_MODES = {"longitudinal": (True, False), "lateral": (False, True), "both": (True, True)}


def action_flags(mode: str) -> tuple[bool, bool]:
    """``(longitudinal, lateral)`` of an action mode; ``ValueError`` on an unknown one."""
    if mode not in ACTION_MODES:
        raise ValueError(f"unknown action_mode {mode!r}; expected one of {sorted(ACTION_MODES)}")
    return ACTION_MODES[mode]


def action_mode(longitudinal: bool, lateral: bool) -> str:
    """Inverse of :func:`action_flags` (e.g. from an env_config ``ContinuousAction`` dict)."""
    for mode, flags in ACTION_MODES.items():
        if flags == (bool(longitudinal), bool(lateral)):
            return mode
    raise ValueError("ContinuousAction needs longitudinal and/or lateral control")


class ContinuousScenario:
    """Mixin: sets the ``longitudinal`` / ``lateral`` flags read by ``DrivingEnv`` from ``action_mode``."""

    default_action_mode = "both"

    def _set_action_mode(self, mode: str | None) -> None:
        self.action_mode = self.default_action_mode if mode is None else mode
        self.longitudinal, self.lateral = action_flags(self.action_mode)


def with_action_mode(env, mode: str):
    """The same environment (frequencies, params) with another action mode.

    >>> env = with_action_mode(envs_jax.make("racetrack"), "both")   # actions [2, 2]
    """
    from envs_jax.env import DrivingEnv

    scenario = env.scenario
    if scenario.discrete:
        raise ValueError(f"{env.name}: action modes only apply to continuous-action scenarios")
    action_flags(mode)
    if getattr(scenario, "action_mode", None) == mode:
        return env
    return DrivingEnv(type(scenario)(action_mode=mode), env.simulation_frequency, env.policy_frequency,
                      env.default_params)
