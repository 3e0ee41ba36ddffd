"""Every bad input is refused with an error that names it and says what is wrong; nothing non-finite is carried on."""

import gc
import io
import re
import subprocess
import sys
import threading
import warnings
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from gymnasium.wrappers import NormalizeObservation
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
from test_mpail import TINY_PLANNER, make_model, pendulum_trajectories
from torch import nn

from sb3_mpail import MPAIL
from sb3_mpail.demos import load_demos
from sb3_mpail.mppi.sampling import ActionSampler
from sb3_mpail.policies import MPPIPolicy

OBSERVATION_SPACE = spaces.Box(-np.inf, np.inf, (3,), np.float32)


@pytest.fixture(scope="module")
def demos():
    return pendulum_trajectories()


@pytest.fixture(scope="module")
def model(demos):
    return make_model(demos)


# --- non-finite observations, states and plans


@pytest.mark.parametrize("bad_value", [np.nan, np.inf, -np.inf])
def test_predict_refuses_a_non_finite_observation_naming_its_env(model, bad_value):
    observations = np.array([[1.0, 0.0, 0.5], [1.0, bad_value, 0.5], [0.0, 1.0, 0.0]], np.float32)
    with pytest.raises(ValueError, match=r"The observation passed to predict holds NaN or infinite values for env 1: "):
        model.predict(observations)
    with pytest.raises(ValueError, match="for env 0: "):  # one observation, not a batch
        model.predict(observations[1])


def test_predict_refuses_a_non_finite_state_naming_its_envs(model):
    observations = np.zeros((3, 3), np.float32)
    _, plans = model.predict(observations)
    plans[[0, 2], 1, 0] = np.nan
    with pytest.raises(ValueError, match=r"The state passed to predict holds NaN or infinite values for envs \[0, 2\]"):
        model.predict(observations, state=plans)


class NaNCostAbove(nn.Module):
    """A step cost that is NaN where ``sin(theta)`` exceeds ``threshold``: a model gone wrong on part of the space."""

    def __init__(self, threshold: float):
        super().__init__()
        self.threshold = threshold

    def forward(self, states: th.Tensor, next_states: th.Tensor) -> th.Tensor:
        return th.where(states[..., 1] > self.threshold, th.nan, 0.0)


def test_predict_refuses_to_return_a_non_finite_plan_naming_its_env_and_plans_on_afterwards(demos):
    policy_kwargs = dict(TINY_PLANNER, step_cost=NaNCostAbove(0.0))
    model = make_model(demos, policy_kwargs=policy_kwargs)
    observations = np.array([[1.0, -0.5, 0.0], [1.0, 0.5, 0.0]], np.float32)
    with pytest.raises(
        ValueError,
        match=r"The plan made from a finite observation and state holds NaN .* for env 1: .*"
        r"the step cost, value or dynamics model returned NaN",
    ):
        model.predict(observations)
    actions, plans = model.predict(observations[:1])
    assert np.isfinite(actions).all() and np.isfinite(plans).all()


class NaNObservationAt(gym.Wrapper):
    """Returns a NaN observation at step ``step`` of its first episode (0: the first reset)."""

    def __init__(self, env: gym.Env, step: int):
        super().__init__(env)
        self.step_to_poison, self.steps = step, 0

    def reset(self, **kwargs):
        observation, info = self.env.reset(**kwargs)
        if self.step_to_poison == 0 and self.steps == 0:
            observation = np.full_like(observation, np.nan)
        return observation, info

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.steps += 1
        if self.steps == self.step_to_poison:
            observation = np.full_like(observation, np.nan)
        return observation, reward, terminated, truncated, info


@pytest.mark.parametrize(
    ("step", "what"),
    [
        (0, "The observation the environment returned"),
        (3, "The observation the environment returned"),
        (5, "The terminal observation the environment returned"),  # episodes of 5 steps
    ],
    ids=["reset", "during-an-episode", "terminal"],
)
def test_training_refuses_a_non_finite_observation_from_the_env_naming_its_env(demos, step, what):
    def make(poisoned: bool):
        env = gym.make("Pendulum-v1", max_episode_steps=5)
        return NaNObservationAt(env, step) if poisoned else env

    env = DummyVecEnv([lambda: make(False), lambda: make(True)])
    model = MPAIL("MlpMPPI", env, demos, n_steps=16, policy_kwargs=TINY_PLANNER)
    with pytest.raises(ValueError, match=f"{what} holds NaN or infinite values for env 1: .*VecCheckNan"):
        model.learn(32)


def test_training_refuses_a_non_finite_planned_action_naming_its_envs(demos):
    model = make_model(demos, n_envs=2, policy_kwargs=dict(TINY_PLANNER, step_cost=NaNCostAbove(-2.0)))
    with pytest.raises(ValueError, match=r"The action planned from a finite observation holds NaN .* for envs \[0, 1\] "):
        model.learn(32)
    assert model.num_timesteps == 0


# --- constructor arguments


def refusal(setting: str, value, expected: str) -> str:
    """The whole message refusing ``value`` for ``setting``, as a regular expression."""
    return f"^{re.escape(f'{setting} must be {expected}; got {value!r}.')}$"


@pytest.mark.parametrize(
    ("setting", "value", "expected"),
    [
        ("n_steps", 0, "a positive integer"),
        ("n_steps", 2.5, "a positive integer"),
        ("gamma", 1.5, "a number in [0, 1]"),
        ("gae_lambda", -0.1, "a number in [0, 1]"),
        ("n_epochs", 0, "a positive integer"),
        ("n_minibatches", 0, "a positive integer"),
        ("discriminator_learning_rate", 0.0, "a finite number > 0"),
        ("discriminator_learning_rate", "1e-4", "a finite number > 0"),  # what YAML makes of 1e-4
        ("discriminator_betas", (0.5, 1.0), "two numbers in [0, 1)"),
        ("discriminator_l2", -1e-3, "a finite number >= 0"),
        ("discriminator_update_interval", 0, "a positive integer"),
        ("discriminator_replay_size", -1, "a non-negative integer"),
        ("discriminator_gradient_penalty", -1.0, "a finite number >= 0"),
        ("value_learning_rate", -1e-3, "a finite number > 0"),
        ("value_betas", (0.9,), "two numbers in [0, 1)"),
        ("value_clip", 0.0, "a finite number > 0"),
        ("max_grad_norm", float("inf"), "a finite number > 0"),
        ("initial_temperature", 0.0, "a finite number > 0"),
        ("temperature_decay", 1.0, "a number in [0, 1)"),
        ("min_temperature", 0.0, "a finite number > 0"),
        ("agent_reward_mean", float("nan"), "a finite number or None"),
        ("agent_reward_mean", "0.2", "a finite number or None"),
        ("policy_average_rate", 0.0, "a number in (0, 1] or None"),
        ("policy_average_rate", 1.5, "a number in (0, 1] or None"),
        ("stats_window_size", 0, "a positive integer"),
        ("policy_kwargs", "dict(n_samples=16)", "a dict or None"),
        ("verbose", -1, "a non-negative integer"),
        ("seed", 1.5, "a Python int or None"),
        ("seed", np.int64(1), "a Python int or None"),
    ],
)
def test_an_out_of_range_mpail_setting_is_refused_naming_it(setting, value, expected):
    with pytest.raises(ValueError, match=refusal(setting, value, expected)):
        MPAIL("MlpMPPI", "Pendulum-v1", **{setting: value})


@pytest.mark.parametrize(
    ("setting", "value", "expected"),
    [
        ("n_samples", 0, "a positive integer"),
        ("n_samples", True, "a positive integer"),
        ("horizon", 0, "a positive integer"),
        ("n_iterations", 0, "a positive integer"),
        ("noise_std", -0.3, "a finite number >= 0, or a sequence of such values, one per action dimension (1)"),
        ("noise_std", [0.3, 0.3], "a finite number >= 0, or a sequence of such values, one per action dimension (1)"),
        ("markup", 0.0, "a finite number > 0"),
        ("discriminator_hidden_sizes", (32, 0), "a sequence of positive integers"),
        ("value_hidden_sizes", 32, "a sequence of positive integers"),
        ("discriminator_ensemble_size", 0, "a positive integer"),
        ("discriminator_disagreement", -1.0, "a finite number >= 0"),
        ("value_ensemble_size", 1.5, "a positive integer"),
        ("value_disagreement", -1.0, "a finite number >= 0"),
        ("reward_form", "gail", "one of ['logit', 'softplus', 'capped']"),
        ("reward_offset", float("nan"), "a finite number"),
        ("dynamics_kwargs", "dict()", "a dict or None"),
        ("sampler_kwargs", [0.2], "a dict or None"),
        ("compile_planner", "fastest", "False, True or a torch.compile mode (one of torch._inductor.list_mode_options())"),
    ],
)
def test_an_out_of_range_planner_setting_is_refused_naming_it(setting, value, expected):
    with pytest.raises(ValueError, match=refusal(setting, value, expected)):
        MPAIL("MlpMPPI", "Pendulum-v1", policy_kwargs={setting: value})


def test_every_bad_setting_is_named_at_once():
    with pytest.raises(ValueError, match="^n_steps must be .*; got 0. gamma must be .*; got 2. min_temperature must be"):
        MPAIL("MlpMPPI", "Pendulum-v1", n_steps=0, gamma=2, min_temperature=-1.0)


@pytest.mark.parametrize(
    "value_setting", [dict(value_ensemble_size=3), dict(value_layer_norm=True), dict(concave_value=True)], ids=str
)
def test_a_value_network_setting_with_the_policy_prior_is_refused_naming_it(value_setting):
    (name,) = value_setting
    with pytest.raises(ValueError, match=f"value network is neither trained nor planned with, so {name} would change nothing"):
        MPPIPolicy(spaces.Box(-1.0, 1.0, (4,), np.float32), spaces.Box(-1.0, 1.0, (2,), np.float32), dynamics="learned",
                   policy_prior=True, **value_setting)  # fmt: skip


def test_a_reward_offset_with_an_agent_reward_mean_is_refused_naming_both():
    with pytest.raises(ValueError, match=r"agent_reward_mean \(0.2\) sets .* reward_offset \(3.0\) would change nothing"):
        MPAIL("MlpMPPI", "Pendulum-v1", agent_reward_mean=0.2, policy_kwargs=dict(reward_offset=3.0))


def test_an_unknown_sampler_is_refused_naming_the_known_ones():
    with pytest.raises(ValueError, match=r"Unknown sampler 'uniform': expected one of \['delta', 'gaussian'\]"):
        MPAIL("MlpMPPI", "Pendulum-v1", policy_kwargs=dict(sampler="uniform"))


def test_settings_at_the_edges_of_their_ranges_are_accepted():
    edges = dict(
        gamma=1.0,
        gae_lambda=0.0,
        discriminator_l2=0.0,
        discriminator_replay_size=0,
        temperature_decay=0.0,
        discriminator_betas=[0.0, 0.0],
        seed=3,
        n_steps=np.int32(1),
    )
    planner = dict(
        n_samples=1,
        horizon=1,
        n_iterations=1,
        noise_std=np.array([0.0]),
        discriminator_hidden_sizes=(),
        compile_planner="reduce-overhead",
    )
    model = MPAIL("MlpMPPI", "Pendulum-v1", policy_kwargs=planner, **edges)
    assert isinstance(model.policy, MPPIPolicy)
    two_actions = spaces.Box(-1.0, 1.0, (2,), np.float32)
    MPPIPolicy(spaces.Box(-1.0, 1.0, (4,), np.float32), two_actions, dynamics="learned", noise_std=[0.3, 0.1])


def test_load_refuses_an_out_of_range_setting_naming_it(model, tmp_path):
    model.save(tmp_path / "model.zip")
    with pytest.raises(ValueError, match="^n_steps must be a positive integer; got 0."):
        MPAIL.load(tmp_path / "model.zip", n_steps=0)


# --- model files


@pytest.fixture(scope="module")
def model_file(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "model.zip"
    model.save(path)
    return path


@pytest.mark.parametrize("fraction", [0.1, 0.5, 0.9, 0.999])
def test_load_of_a_truncated_file_names_the_file_and_says_it_is_truncated(model_file, tmp_path, fraction):
    data = model_file.read_bytes()
    truncated = tmp_path / "truncated.zip"
    truncated.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(ValueError, match=f"MPAIL model file {truncated} is truncated"):
        MPAIL.load(truncated)
    with pytest.raises(ValueError, match=r"MPAIL model file <file object> is truncated"):
        MPAIL.load(io.BytesIO(truncated.read_bytes()))


def test_load_of_a_truncated_file_names_it_under_python_dash_o(model_file, tmp_path):
    truncated = tmp_path / "truncated.zip"
    truncated.write_bytes(model_file.read_bytes()[:5000])
    script = f"from sb3_mpail import MPAIL\nMPAIL.load({str(truncated)!r})"
    run = subprocess.run([sys.executable, "-O", "-c", script], capture_output=True, text=True, timeout=300)
    assert run.returncode == 1
    assert f"ValueError: MPAIL model file {truncated} is truncated" in run.stderr, run.stderr[-2000:]


def test_load_of_a_corrupted_file_names_the_damaged_member(model_file, tmp_path):
    data = bytearray(model_file.read_bytes())
    data[data.index(b"policy.pth") + 200] ^= 0xFF  # a byte of the policy's weights
    corrupted = tmp_path / "corrupted.zip"
    corrupted.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=f"MPAIL model file {corrupted} is damaged: its member policy.pth fails its CRC"):
        MPAIL.load(corrupted)


@pytest.mark.parametrize(("content", "problem"), [(b"", r"is empty \(0 bytes\)"), (b"not a zip", "is truncated or not a zip")])
def test_load_of_an_empty_or_non_zip_file_names_the_file_and_the_problem(tmp_path, content, problem):
    path = tmp_path / "model.zip"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=f"MPAIL model file {path} {problem}"):
        MPAIL.load(path)


def test_load_of_a_missing_file_names_it(tmp_path):
    missing = f"MPAIL model file {tmp_path / 'nowhere'} does not exist (nor {tmp_path / 'nowhere.zip'})."
    with pytest.raises(FileNotFoundError, match=re.escape(missing)):
        MPAIL.load(tmp_path / "nowhere")


def test_load_of_another_algorithms_file_says_it_is_not_an_mpail_model(tmp_path):
    PPO("MlpPolicy", "Pendulum-v1", n_steps=64).save(tmp_path / "ppo")
    with pytest.raises(
        ValueError,
        match=f"Model file {tmp_path / 'ppo.zip'} is not an MPAIL model: it lacks MPAIL's "
        r"settings .*policy class comes from stable_baselines3.common.policies",
    ):
        MPAIL.load(tmp_path / "ppo")


# --- demo files


@pytest.mark.parametrize(
    ("write", "problem"),
    [
        (lambda path: path.write_bytes(b""), r"is empty \(0 bytes\)"),
        (lambda path: np.savez(path, obs=np.zeros((0, 5, 3), np.float32)), "holds no episodes"),
        (lambda path: np.savez(path, obs=np.zeros((2, 1, 3), np.float32)), "episode 0 must hold at least two observations"),
        (lambda path: path.write_bytes(b"PK\x03\x04 half an archive"), "is not a readable .npz archive"),
        (lambda path: path.write_text("obs = 1, 2, 3"), "is not a readable .npz archive"),
    ],
    ids=["empty-file", "no-demos", "one-observation", "truncated", "text"],
)
def test_a_bad_demo_file_is_refused_naming_the_file_and_the_problem(tmp_path, write, problem):
    path = tmp_path / "demos.npz"
    write(path)
    with pytest.raises(ValueError, match=f"Demo file {path}:? {problem}"):
        load_demos(path, OBSERVATION_SPACE)


def test_an_npy_demo_file_is_refused_as_not_an_npz_archive(tmp_path):
    np.save(tmp_path / "demos.npy", np.zeros((2, 5, 3), np.float32))
    with pytest.raises(ValueError, match=f"Demo file {tmp_path / 'demos.npy'} is a single .npy array, not an .npz"):
        load_demos(tmp_path / "demos.npy", OBSERVATION_SPACE)


def test_an_empty_sequence_of_demo_trajectories_is_refused():
    with pytest.raises(ValueError, match="The sequence of demo trajectories holds no episodes"):
        load_demos([], OBSERVATION_SPACE)


# --- environments with normalised observations


def test_an_env_with_vecnormalize_observations_is_refused_saying_why(demos):
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2))
    with pytest.raises(
        ValueError,
        match=r"MPAIL needs the environment's raw observations, but this one is wrapped in "
        r"VecNormalize\(norm_obs=True\): the planner rolls observations through a "
        r"dynamics model of the raw states.*normalize: false",
    ):
        MPAIL("MlpMPPI", env, demos, policy_kwargs=TINY_PLANNER)


def test_set_env_refuses_an_env_with_normalised_observations(model):
    with pytest.raises(ValueError, match=r"wrapped in VecNormalize\(norm_obs=True\)"):
        model.set_env(VecNormalize(make_vec_env("Pendulum-v1", n_envs=1)))
    with pytest.raises(ValueError, match="wrapped in gymnasium's NormalizeObservation \\(env 0\\)"):
        model.set_env(NormalizeObservation(gym.make("Pendulum-v1")))
    assert not isinstance(model.env, VecNormalize)


def test_an_env_with_normalised_rewards_only_is_accepted(demos):
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1), norm_obs=False)
    model = MPAIL("MlpMPPI", env, demos, n_steps=8, policy_kwargs=TINY_PLANNER).learn(8)
    assert model.num_timesteps == 8


# --- predict's other inputs


@pytest.mark.parametrize("episode_start", [np.zeros(2, bool), np.zeros((3, 1), bool), True, ["yes", "no", "no"]])
def test_predict_refuses_an_episode_start_that_is_not_one_flag_per_env(model, episode_start):
    observations = np.zeros((3, 3), np.float32)
    _, plans = model.predict(observations)
    with pytest.raises(ValueError, match=r"episode_start must hold one flag per env \(3, shape \(3,\)\); got"):
        model.predict(observations, state=plans, episode_start=episode_start)
    with pytest.raises(ValueError, match="episode_start must hold one flag per env"):  # also without a state
        model.predict(observations, episode_start=episode_start)


def test_predict_takes_a_single_flag_as_episode_start_of_a_single_observation(model):
    observation = np.zeros(3, np.float32)
    _, plan = model.predict(observation)
    fresh = model.predict(observation, state=plan, episode_start=True, deterministic=True)[0]
    np.testing.assert_array_equal(fresh, model.predict(observation, deterministic=True)[0])


@pytest.mark.parametrize("huge", [1e30, 1e39])
def test_predict_refuses_observations_too_large_for_float32_planning_naming_the_env(model, huge):
    observations = np.array([[1.0, 0.0, 0.5], [1.0, 0.0, huge]])
    with pytest.raises(ValueError, match=r"holds values beyond \+-1e\+18 for envs \[1\] .* the planner computes in float32"):
        model.predict(observations)


# --- learn's arguments, and what learning needs


@pytest.mark.parametrize("total_timesteps", [-100, float("nan"), "400", None, 10.5])
def test_learn_refuses_a_budget_that_is_not_a_whole_number_of_steps(model, total_timesteps):
    expected = rf"total_timesteps must be a whole number >= 0; got {re.escape(repr(total_timesteps))}"
    with pytest.raises(ValueError, match=expected):
        model.learn(total_timesteps)


def test_learn_refuses_a_log_interval_of_zero(model):
    with pytest.raises(ValueError, match="log_interval must be a positive integer or None; got 0"):
        model.learn(16, log_interval=0)


def test_learn_takes_a_whole_float_budget(demos):
    assert make_model(demos).learn(16.0).num_timesteps == 16


def test_learn_on_a_model_loaded_without_env_says_how_to_give_one(model, demos, tmp_path):
    model.save(tmp_path / "model")
    loaded = MPAIL.load(tmp_path / "model")
    loaded.set_demos(demos)
    with pytest.raises(ValueError, match=r"MPAIL has no environment to learn in .* model.set_env\(env\)"):
        loaded.learn(16)


def test_load_refuses_a_setting_that_mpail_does_not_have(model, tmp_path):
    model.save(tmp_path / "model")
    with pytest.raises(ValueError, match=r"MPAIL.load got settings that MPAIL does not have: \['n_step'\]"):
        MPAIL.load(tmp_path / "model", n_step=32)
    assert MPAIL.load(tmp_path / "model", n_steps=32, stats_window_size=7)._stats_window_size == 7


# --- policy settings


@pytest.mark.parametrize("setting", ["use_step_cost", "use_terminal_value", "use_spectral_norm"])
def test_flags_given_as_strings_are_refused(demos, setting):
    with pytest.raises(ValueError, match=f"{setting} must be True or False; got 'no'"):
        make_model(demos, policy_kwargs=dict(TINY_PLANNER, **{setting: "no"}))


def test_an_mppi_policy_refuses_a_discrete_action_space():
    with pytest.raises(ValueError, match=r"MPPI policies plan continuous actions .*; got Discrete\(3\)"):
        MPPIPolicy(OBSERVATION_SPACE, spaces.Discrete(3))


def test_an_mppi_policy_refuses_infinite_action_bounds_under_python_dash_o():
    code = (
        "import numpy as np; from gymnasium import spaces; from sb3_mpail.policies import MPPIPolicy\n"
        "box = spaces.Box(-np.inf, np.inf, (3,), np.float32)\n"
        "MPPIPolicy(box, spaces.Box(-np.inf, np.inf, (1,), np.float32))"
    )
    result = subprocess.run([sys.executable, "-O", "-c", code], capture_output=True, text=True)
    assert "MPPI samples actions relative to the action space's range, so its bounds must be finite" in result.stderr


# --- saving


def test_save_over_a_symbolic_link_writes_its_target(model, tmp_path):
    target = tmp_path / "models" / "latest.zip"
    target.parent.mkdir()
    target.write_bytes(b"old")
    link = tmp_path / "model.zip"
    link.symlink_to(target)
    model.save(link)
    assert link.is_symlink() and target.stat().st_size > 3
    MPAIL.load(link)


def test_save_refuses_to_overwrite_a_read_only_file(model, tmp_path):
    path = tmp_path / "model.zip"
    path.write_bytes(b"keep me")
    path.chmod(0o444)
    with pytest.raises(PermissionError, match="is read-only: MPAIL.save does not overwrite it"):
        model.save(path)
    assert path.read_bytes() == b"keep me"


def test_a_partial_file_left_by_a_killed_save_is_removed_by_the_next_save(model, tmp_path):
    stale = tmp_path / "model.zip.partial"
    stale.write_bytes(b"a save killed half-way")
    model.save(tmp_path / "model")
    assert not stale.exists()
    MPAIL.load(tmp_path / "model")


class KeepDimCost(nn.Module):
    """A cost that keeps the state dimension: ``(..., 1)`` instead of one number per transition."""

    def forward(self, states, next_states):
        return next_states[..., :1].square()


class KeepDimValue(nn.Module):
    def forward(self, states):
        return states[..., :1]


@pytest.mark.parametrize("setting, module", [("step_cost", KeepDimCost()), ("terminal_value", KeepDimValue())])
def test_a_users_cost_or_value_of_the_wrong_shape_is_refused_naming_it(demos, setting, module):
    model = make_model(demos, policy_kwargs=dict(TINY_PLANNER, **{setting: module}))
    expected = rf"{setting} must return a torch tensor of one number per state, shape \(3?,? ?1, 16\)"
    with pytest.raises(ValueError, match=expected):
        model.predict(np.zeros(3, np.float32))


# --- held-out probes: settings and inputs once taken silently or crashing unclearly


class SinCosSwapped(gym.ObservationWrapper):
    """Pendulum's observation reordered to ``[sin, cos, w]``: the spec id is Pendulum-v1's, the state is not."""

    def observation(self, observation):
        return observation[[1, 0, 2]]


def test_the_automatic_pendulum_model_plans_with_the_env_s_gravity(demos):
    env = make_vec_env("Pendulum-v1", n_envs=1, env_kwargs=dict(g=5.0))
    assert MPAIL("MlpMPPI", env, demos, policy_kwargs=TINY_PLANNER).policy.dynamics.gravity == 5.0
    given = dict(TINY_PLANNER, dynamics_kwargs=dict(gravity=7.0))  # the user's own setting wins
    assert MPAIL("MlpMPPI", env, demos, policy_kwargs=given).policy.dynamics.gravity == 7.0
    assert MPAIL("MlpMPPI", "Pendulum-v1", policy_kwargs=TINY_PLANNER).policy.dynamics.gravity == 10.0


def test_an_env_with_an_observation_wrapper_gets_no_automatic_model_and_is_told_how_to_give_one(demos):
    env = make_vec_env("Pendulum-v1", n_envs=1, wrapper_class=SinCosSwapped)
    with pytest.raises(ValueError, match=r"wrapped in a gymnasium ObservationWrapper \(.*SinCosSwapped.*\).*"
                                         r"pass policy_kwargs=dict\(dynamics=\.\.\.\)"):  # fmt: skip
        MPAIL("MlpMPPI", env, demos, policy_kwargs=TINY_PLANNER)
    chosen = MPAIL("MlpMPPI", env, demos, policy_kwargs=dict(TINY_PLANNER, dynamics="learned"))
    assert type(chosen.policy.dynamics).__name__ == "LearnedDynamics"


@pytest.mark.parametrize("max_delta", [[0.2, 0.2], float("nan"), 0.0, "0.2"])
def test_a_delta_sampler_s_max_delta_must_be_positive_and_one_per_action_dimension(max_delta):
    expected = "a finite number > 0, or a sequence of such values, one per action dimension (1)"
    with pytest.raises(ValueError, match=refusal("max_delta", max_delta, expected)):
        MPAIL("MlpMPPI", "Pendulum-v1", policy_kwargs=dict(sampler="delta", sampler_kwargs=dict(max_delta=max_delta)))


def test_a_min_temperature_above_the_initial_temperature_is_refused_naming_both():
    with pytest.raises(ValueError, match=r"min_temperature \(10.0\) must not exceed initial_temperature \(1.0\)"):
        MPAIL("MlpMPPI", "Pendulum-v1", initial_temperature=1.0, min_temperature=10.0)


def test_predict_refuses_a_nan_episode_start_flag_naming_its_env(model):
    with pytest.raises(ValueError, match=r"The episode_start passed to predict holds NaN or infinite values for env 0"):
        model.predict(np.zeros((2, 3), np.float32), episode_start=[np.nan, 0.0])


def test_predict_refuses_complex_observations_rather_than_dropping_their_imaginary_parts(model):
    with pytest.raises(ValueError, match=r"The observation passed to predict holds complex numbers \(complex64\)"):
        model.predict(np.zeros(3, np.complex64) + 5j)


def test_a_users_float64_step_cost_is_cast_to_the_planner_s_dtype_and_a_bool_one_refused_naming_it(demos):
    observation = np.array([1.0, 0.0, 0.5], np.float32)
    in_float32 = make_model(demos, policy_kwargs=dict(TINY_PLANNER, step_cost=lambda s, ns: ns[..., 2].square()))
    in_float64 = make_model(demos, policy_kwargs=dict(TINY_PLANNER, step_cost=lambda s, ns: ns[..., 2].double().square()))
    expected = in_float32.predict(observation, deterministic=True)[0]
    np.testing.assert_allclose(in_float64.predict(observation, deterministic=True)[0], expected, atol=1e-5)
    flags = make_model(demos, policy_kwargs=dict(TINY_PLANNER, step_cost=lambda s, ns: ns[..., 2] > 0))
    with pytest.raises(ValueError, match=r"step_cost must return real numbers .*; got dtype torch.bool"):
        flags.predict(observation)


def test_a_step_cost_taking_the_wrong_number_of_arguments_is_refused_naming_it_and_the_signature():
    with pytest.raises(TypeError, match=r"step_cost must be a callable c\(states, next_states\) -> costs; .*<lambda>"
                                        r"\(states\) cannot be called so"):  # fmt: skip
        MPPIPolicy(OBSERVATION_SPACE, spaces.Box(-2, 2, (1,), np.float32), "pendulum", step_cost=lambda states: states[..., 0])


class SampleMajorSampler(ActionSampler):
    """A user's sampler returning ``(n_envs, n_samples, horizon, action_dim)`` instead of time-major samples."""

    def forward(self, plan, n_samples, generator):
        noise = self.standard_noise(plan, n_samples, generator)
        return (noise + plan.transpose(0, 1).unsqueeze(2)).clamp(-2, 2).permute(1, 2, 0, 3)


def test_a_sampler_returning_the_wrong_shape_is_refused_naming_the_shape_expected(demos):
    sampler = SampleMajorSampler(np.array([-2.0]), np.array([2.0]))
    model = make_model(demos, policy_kwargs=dict(TINY_PLANNER, sampler=sampler))
    expected = "sampler must return (H, n_envs, N, A) = (3, 1, 16, 1) action sequences; got shape (1, 16, 3, 1)"
    with pytest.raises(ValueError, match=re.escape(expected)):
        model.predict(np.zeros(3, np.float32))


@pytest.mark.parametrize("callback", ["eval", 3, [lambda locals_, globals_: True]])
def test_learn_refuses_a_callback_that_is_not_one_naming_it(model, callback):
    expected = "None, a BaseCallback, a list of BaseCallbacks or a function f(locals, globals) -> bool"
    with pytest.raises(ValueError, match=refusal("callback", callback, expected)):
        model.learn(16, callback=callback)


def test_load_with_demos_says_to_set_them_after_loading(model_file, demos):
    with pytest.raises(ValueError, match=r"MPAIL.load takes no demos .* model.set_demos\(demos\)"):
        MPAIL.load(model_file, demos=demos)


def test_load_refuses_to_switch_the_temperature_mode_saying_it_is_fixed_at_training(model_file):
    with pytest.raises(ValueError, match=r"temperature is fixed when a model is made: this one's is 'decay'; got 'learned'"):
        MPAIL.load(model_file, temperature="learned")
    assert MPAIL.load(model_file, temperature="decay").temperature_mode == "decay"


def test_load_finds_the_zip_file_beside_a_directory_of_the_same_name(model, tmp_path):
    (tmp_path / "m").mkdir()
    model.save(tmp_path / "m")
    MPAIL.load(tmp_path / "m")
    (tmp_path / "d").mkdir()
    with pytest.raises(ValueError, match=f"MPAIL model file {tmp_path / 'd'} is a directory, not a model file"):
        MPAIL.load(tmp_path / "d")


def test_load_of_a_file_whose_data_member_is_not_json_says_so(model_file, tmp_path):
    path = tmp_path / "bad_json.zip"
    with zipfile.ZipFile(model_file) as source, zipfile.ZipFile(path, "w") as target:
        for item in source.infolist():
            target.writestr(item, b"{not json" if item.filename == "data" else source.read(item.filename))
    with pytest.raises(ValueError, match=re.escape(f"MPAIL model file {path}: its 'data' member (the model's settings) is "
                                                   "not JSON")):  # fmt: skip
        MPAIL.load(path)


class LockedCost(nn.Module):
    """A step cost holding a lock: cloudpickle cannot save it."""

    def __init__(self):
        super().__init__()
        self.lock = threading.Lock()

    def forward(self, states, next_states):
        return next_states[..., 2].square()


def test_save_of_an_unpicklable_policy_setting_names_it_and_leaves_no_file_open(demos, tmp_path):
    model = make_model(demos, policy_kwargs=dict(TINY_PLANNER, step_cost=LockedCost()))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(TypeError, match=r"policy_kwargs\['step_cost'\] \(a LockedCost\) cannot be saved"):
            model.save(tmp_path / "locked")
        gc.collect()  # an unclosed file is reported when it is collected
    assert [str(warning.message) for warning in caught if issubclass(warning.category, ResourceWarning)] == []
    assert list(tmp_path.iterdir()) == []
