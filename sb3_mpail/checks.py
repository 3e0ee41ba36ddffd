"""Checks that refuse bad input with an error naming it: constructor arguments, and per-env arrays that must be finite."""

import inspect
import math
import numbers
from collections.abc import Mapping, Sequence
from typing import Any, Callable, NamedTuple, Tuple

import numpy as np
from gymnasium.wrappers import NormalizeObservation
from stable_baselines3.common.vec_env import VecEnv, unwrap_vec_normalize


class Rule(NamedTuple):
    """What an argument must be: ``holds(value)``, and ``expected`` as an error message says it."""

    expected: str
    holds: Callable[[Any], bool]


def _is_integer(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def _is_sequence(value: Any) -> bool:
    return isinstance(value, Sequence) and not isinstance(value, str)


POSITIVE_INTEGER = Rule("a positive integer", lambda value: _is_integer(value) and value > 0)
NON_NEGATIVE_INTEGER = Rule("a non-negative integer", lambda value: _is_integer(value) and value >= 0)
#: a seed: a Python int (Python's ``random.seed`` refuses numpy's) or None
SEED = Rule("a Python int or None", lambda value: value is None or (isinstance(value, int) and not isinstance(value, bool)))
FINITE_NUMBER = Rule("a finite number", _is_number)
POSITIVE_NUMBER = Rule("a finite number > 0", lambda value: _is_number(value) and value > 0)
NON_NEGATIVE_NUMBER = Rule("a finite number >= 0", lambda value: _is_number(value) and value >= 0)
UNIT_INTERVAL = Rule("a number in [0, 1]", lambda value: _is_number(value) and 0 <= value <= 1)
FRACTION = Rule("a number in [0, 1)", lambda value: _is_number(value) and 0 <= value < 1)
#: a factor that shrinks (or keeps) what it multiplies, never to 0: a decay
DECAY_FACTOR = Rule("a number in (0, 1]", lambda value: _is_number(value) and 0 < value <= 1)
BETAS = Rule(
    "two numbers in [0, 1)", lambda value: _is_sequence(value) and len(value) == 2 and all(map(FRACTION.holds, value))
)
HIDDEN_SIZES = Rule(
    "a sequence of positive integers", lambda value: _is_sequence(value) and all(map(POSITIVE_INTEGER.holds, value))
)
#: a flag: Python's or numpy's booleans, never a string such as ``"no"`` (which Python reads as true)
BOOLEAN = Rule("True or False", lambda value: isinstance(value, (bool, np.bool_)))
#: an env-step budget: whole numbers, also as floats (``learn(1e6)``), never strings, NaN or negatives
TIMESTEPS = Rule("a whole number >= 0", lambda value: _is_number(value) and value >= 0 and float(value).is_integer())
OPTIONAL_POSITIVE_INTEGER = Rule("a positive integer or None", lambda value: value is None or POSITIVE_INTEGER.holds(value))
OPTIONAL_FINITE_NUMBER = Rule("a finite number or None", lambda value: value is None or _is_number(value))
OPTIONAL_DECAY_FACTOR = Rule("a number in (0, 1] or None", lambda value: value is None or DECAY_FACTOR.holds(value))
OPTIONAL_UNIT_INTERVAL = Rule("a number in [0, 1] or None", lambda value: value is None or UNIT_INTERVAL.holds(value))
OPTIONAL_DICT = Rule("a dict or None", lambda value: value is None or isinstance(value, Mapping))


def one_of(choices: Sequence[str]) -> Rule:
    """A rule for a name among ``choices``."""
    return Rule(f"one of {list(choices)}", lambda value: isinstance(value, str) and value in choices)


def per_action_dimension(rule: Rule, action_dim: int) -> Rule:
    """
    ``rule`` for one value shared by every action dimension, or for each of ``action_dim`` values.

    :param rule: what each value must be
    :param action_dim: how many values a sequence must hold
    """

    def holds(value: Any) -> bool:
        values = list(value) if _is_sequence(value) or np.ndim(value) == 1 else [value]
        return len(values) in {1, action_dim} and all(map(rule.holds, values))

    return Rule(f"{rule.expected}, or a sequence of such values, one per action dimension ({action_dim})", holds)


def check_arguments(**arguments: Tuple[Any, Rule]) -> None:
    """
    Refuses arguments that break their rules, naming each of them with its value.

    :param arguments: per argument name, its value and the :class:`Rule` it must keep
    :raises ValueError: one or more arguments break their rules (all of them are named)
    """
    errors = [
        f"{name} must be {rule.expected}; got {value!r}." for name, (value, rule) in arguments.items() if not rule.holds(value)
    ]
    if errors:
        raise ValueError(" ".join(errors))


def check_signature(function: Callable, name: str, signature: str, n_arguments: int) -> None:
    """
    Refuses a callable that cannot be called with ``n_arguments`` positional arguments (for a module, its ``forward``),
    naming the setting and the signature it must have. Callables without a signature Python can read are let through.

    :param function: the callable given
    :param name: the setting it was given as, which the message names (e.g. ``"step_cost"``)
    :param signature: the signature expected, as the message shows it (e.g. ``"c(states, next_states) -> costs"``)
    :param n_arguments: how many positional arguments it is called with
    :raises TypeError: it cannot be called with that many
    """
    target = getattr(function, "forward", function)  # an nn.Module's own signature is (*args, **kwargs)
    try:
        parameters = inspect.signature(target)
    except (TypeError, ValueError):  # builtins and some extension types have none
        return
    try:
        parameters.bind(*range(n_arguments))
    except TypeError as error:
        qualname = getattr(target, "__qualname__", type(function).__qualname__)
        raise TypeError(
            f"{name} must be a callable {signature}; {qualname}{parameters} cannot be called so: {error}."
        ) from None


def check_finite(array: np.ndarray, what: str, advice: str) -> None:
    """
    Refuses a per-env batch holding NaN or infinite values, naming the envs whose rows hold them.

    :param array: a batch with one leading row per env, e.g. observations ``(n_envs, obs_dim)`` or plans
        ``(n_envs, horizon, action_dim)``
    :param what: what the batch is, as the message names it (e.g. ``"the observation passed to predict"``)
    :param advice: what the user can do about it, appended to the message
    :raises ValueError: some env's row is not finite
    """
    if len(array) == 0:  # no envs
        return
    rows = np.asarray(array).reshape(len(array), -1)
    bad = np.flatnonzero(~np.isfinite(rows).all(axis=1))
    if len(bad) > 0:
        first = f"env {bad[0]}: {rows[bad[0]]}"
        envs = first if len(bad) == 1 else f"envs {bad.tolist()} ({first})"
        raise ValueError(f"{what} holds NaN or infinite values for {envs}; {advice}")


def refuse_normalised_observations(env: VecEnv) -> None:
    """
    Refuses an environment whose observations are normalised (SB3's ``VecNormalize`` with ``norm_obs``, gymnasium's
    ``NormalizeObservation``): the planner rolls them through a dynamics model of the raw states.

    :param env: the environment, wrapped as a ``VecEnv``
    :raises ValueError: its observations are normalised
    """
    vec_normalize = unwrap_vec_normalize(env)
    wrapped = [index for index, is_wrapped in enumerate(env.env_is_wrapped(NormalizeObservation)) if is_wrapped]
    if (vec_normalize is None or not vec_normalize.norm_obs) and not wrapped:
        return
    wrapper = "VecNormalize(norm_obs=True)" if not wrapped else f"gymnasium's NormalizeObservation (env {wrapped[0]})"
    raise ValueError(
        f"MPAIL needs the environment's raw observations, but this one is wrapped in {wrapper}: the planner rolls "
        "observations through a dynamics model of the raw states, and its learned cost and value judge the states that "
        "model predicts. Pass the environment without the wrapper (rl_zoo3: normalize: false). Rewards may stay "
        "normalised (VecNormalize(norm_obs=False)): MPAIL learns its own."
    )
