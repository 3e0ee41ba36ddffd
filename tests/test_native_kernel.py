"""The planner's compiled CPU kernel (sb3_mpail/mppi/native.py): same costs as the torch path, built safely or not at all."""

import platform
import warnings
from pathlib import Path
from typing import Callable

import pytest
import torch as th
from torch import nn

import sb3_mpail.mppi.fused as fused
import sb3_mpail.mppi.native as native
from sb3_mpail.mppi.ensemble import FrozenEnsembleCost
from sb3_mpail.mppi.reward_forms import REWARD_FORMS

# only a machine without a C compiler skips: where there is one (CI), a kernel that fails to build fails these tests
pytestmark = pytest.mark.skipif(native._compiler() is None, reason="no C compiler here")


def frozen_network(layers: list) -> fused.FrozenMlp:
    th.manual_seed(0)
    return fused.freeze_mlp(nn.Sequential(*layers).eval())


def transition_costs(mlp: fused.FrozenMlp, states: th.Tensor, use_kernel: bool, *reward) -> th.Tensor:
    cost = fused.FusedTransitionCost(mlp, states.shape[-1], *reward)
    if use_kernel:
        assert cost.native is not None
    else:
        cost.native = None
    markups = 1.01 ** th.arange(states.shape[0] - 1, dtype=states.dtype)
    with th.no_grad():
        return cost(states, markups, fused.Workspace()).clone()


def rolled_out_states(horizon: int, n_envs: int, n_samples: int, state_dim: int, feature_major: bool) -> th.Tensor:
    generator = th.Generator().manual_seed(1)
    if feature_major:  # as the bicycle's roll-out stores them (see dynamics.feature_major_states)
        columns = th.randn(state_dim, horizon + 1, n_envs, n_samples, generator=generator)
        return columns.permute(1, 2, 3, 0)
    return th.randn(horizon + 1, n_envs, n_samples, state_dim, generator=generator)


@pytest.mark.parametrize("activation", [nn.ReLU(), nn.LeakyReLU(0.2), nn.Tanh()])
@pytest.mark.parametrize("feature_major", [True, False])
def test_kernel_transition_costs_match_the_torch_path(activation, feature_major):
    # widths that are not multiples of the kernel's groups of 4 or 8 outputs, and 3 x 67 columns: a partial last block
    mlp = frozen_network([nn.Linear(14, 17), activation, nn.Linear(17, 6), activation, nn.Linear(6, 1)])
    states = rolled_out_states(horizon=4, n_envs=3, n_samples=67, state_dim=7, feature_major=feature_major)
    kernel, torch_path = transition_costs(mlp, states, True), transition_costs(mlp, states, False)
    assert kernel.shape == (3, 67)
    assert th.allclose(kernel, torch_path, atol=1e-5, rtol=1e-5), (kernel - torch_path).abs().max()


def leaky_relu_network(widths: list) -> nn.Sequential:
    """An MLP in eval mode: LeakyReLU(0.2) layers of ``widths`` (the first the input size), then one output."""
    layers = []
    for n_in, n_out in zip(widths, widths[1:]):
        layers += [nn.Linear(n_in, n_out), nn.LeakyReLU(0.2)]
    return nn.Sequential(*layers, nn.Linear(widths[-1], 1)).eval()


def ensemble_members(widths: list, n_members: int = 5) -> list:
    th.manual_seed(0)
    return [leaky_relu_network(widths) for _ in range(n_members)]


def ensemble_costs(members: list, states: th.Tensor, disagreement: float, use_kernel: bool, *reward) -> th.Tensor:
    frozen = [fused.freeze_mlp(member) for member in members]
    cost = FrozenEnsembleCost.build(frozen, states.shape[-1], disagreement, *reward)
    if use_kernel:
        assert cost.native is not None
    else:
        cost.native = None
    with th.no_grad():
        return cost(states, 1.01 ** th.arange(states.shape[0] - 1, dtype=th.float32), fused.Workspace()).clone()


# one hidden layer; two (the last folded into the output); three (the hidden layers ping-pong past the inputs)
@pytest.mark.parametrize("widths", [[14, 9], [14, 17, 6], [14, 32, 32, 32]])
@pytest.mark.parametrize("feature_major", [True, False])
def test_kernel_ensemble_costs_match_the_torch_path_and_the_ensemble_module(widths, feature_major):
    members = ensemble_members(widths)
    states = rolled_out_states(horizon=4, n_envs=3, n_samples=67, state_dim=7, feature_major=feature_major)
    kernel, torch_path = ensemble_costs(members, states, 1.3, True), ensemble_costs(members, states, 1.3, False)
    with th.no_grad():
        logits = th.stack([member(th.cat([states[:-1], states[1:]], dim=-1))[..., 0] for member in members])
    combined = logits.mean(dim=0) - 1.3 * logits.std(dim=0, unbiased=False)
    module = -(1.01 ** th.arange(4.0))[:, None, None].mul(combined).sum(dim=0)
    assert kernel.shape == (3, 67)
    assert th.allclose(kernel, torch_path, atol=1e-5, rtol=1e-5), (kernel - torch_path).abs().max()
    assert th.allclose(kernel, module, atol=1e-5, rtol=1e-5), (kernel - module).abs().max()


def test_the_kernel_takes_only_ensembles_it_can_evaluate():
    frozen = [fused.native_mlp(fused.freeze_mlp(member)) for member in ensemble_members([14, 9], n_members=3)]
    assert native.NativeEnsemble.from_members(frozen, th.zeros(3), 1.0) is not None
    assert native.NativeEnsemble.from_members(frozen[:1], th.zeros(1), 1.0) is None
    other_inputs = fused.native_mlp(fused.freeze_mlp(ensemble_members([12, 9], n_members=1)[0]))
    assert native.NativeEnsemble.from_members([*frozen[:2], other_inputs], th.zeros(3), 1.0) is None
    too_many = native.load_library().ensemble_max_members() + 1
    assert native.NativeEnsemble.from_members(frozen[:1] * too_many, th.zeros(too_many), 1.0) is None
    ensemble = native.NativeEnsemble.from_members(frozen, th.zeros(3), 1.0)
    with pytest.raises(ValueError, match="takes 14 inputs"):
        ensemble.marked_up_sums(th.randn(3, 10, 6), th.ones(2), True, th.empty(10))
    with pytest.raises(ValueError, match="contiguous output"):
        ensemble.marked_up_sums(th.randn(3, 10, 7), th.ones(2), True, th.empty(9))


def held_rolled_out_states(held_dims: list, n_envs: int = 3, n_samples: int = 67) -> tuple:
    """Feature-major roll-outs whose ``held_dims`` stay at each env's initial values, and those initial states."""
    states = rolled_out_states(horizon=4, n_envs=n_envs, n_samples=n_samples, state_dim=7, feature_major=True)
    initial_states = th.randn(n_envs, 7, generator=th.Generator().manual_seed(2))
    states[..., held_dims] = initial_states[:, None, held_dims]
    return states, initial_states


@pytest.mark.parametrize("held_dims", [[1, 4, 5], list(range(7))])
@pytest.mark.parametrize("hidden_layers", [0, 2])
def test_kernel_costs_with_held_state_dims_match_the_torch_path(held_dims, hidden_layers):
    # 67 samples per env: blocks of 16 or 32 columns straddle two envs, whose held values differ
    mlp = fused.freeze_mlp(leaky_relu_network([14, 17, 6][: hidden_layers + 1]))
    states, initial_states = held_rolled_out_states(held_dims)
    markups = 1.01 ** th.arange(4, dtype=th.float32)
    cost = fused.FusedTransitionCost(mlp, 7)
    cost.hold(held_dims, initial_states)
    with th.no_grad():
        kernel = cost(states, markups, fused.Workspace()).clone()
    torch_path = transition_costs(mlp, states, False)
    assert th.allclose(kernel, torch_path, atol=1e-5, rtol=1e-5), (kernel - torch_path).abs().max()


def marked_up_rewards(logits: th.Tensor, reward_form: str, reward_offset: float) -> th.Tensor:
    """The costs the planner's module path gives ``(horizon, n_envs, n_samples)`` logits: ``-sum_t m_t (r(d) + offset)``."""
    rewards = REWARD_FORMS[reward_form](logits) + reward_offset
    return -(1.01 ** th.arange(float(len(logits))))[:, None, None].mul(rewards).sum(dim=0)


def spread_logits(output_layers: list, logits: Callable[[], th.Tensor]) -> th.Tensor:
    """
    Scales the output layers' weights and shifts their biases so that ``logits()`` spread from -60 to 60 about their
    median: both sides of softplus's threshold of 20, where torch switches to the identity. Returns them.
    """
    with th.no_grad():
        initial = logits()
        for layer in output_layers:
            layer.weight.mul_(120.0 / (initial.max() - initial.min()))
        median = logits().median()
        for layer in output_layers:  # a nonlinear form needs the output bias inside it, not added to the sum
            layer.bias.sub_(median)
        spread = logits()
    assert spread.min() < -20 and spread.max() > 20
    return spread


@pytest.mark.parametrize("reward_form", ["softplus", "capped"])
@pytest.mark.parametrize("hidden_layers", [0, 2])
def test_kernel_costs_in_each_reward_form_match_the_torch_path_and_the_module(reward_form, hidden_layers):
    network = leaky_relu_network([14, 17, 6][: hidden_layers + 1])
    states, initial_states = held_rolled_out_states([1, 4, 5])
    logits = spread_logits([network[-1]], lambda: network(th.cat([states[:-1], states[1:]], dim=-1))[..., 0])
    module = marked_up_rewards(logits, reward_form, 0.7)
    mlp = fused.freeze_mlp(network)
    kernel = transition_costs(mlp, states, True, reward_form, 0.7)
    torch_path = transition_costs(mlp, states, False, reward_form, 0.7)
    held = fused.FusedTransitionCost(mlp, 7, reward_form, 0.7)
    held.hold([1, 4, 5], initial_states)
    with th.no_grad():
        held_kernel = held(states, 1.01 ** th.arange(4, dtype=th.float32), fused.Workspace())
    for costs in (kernel, torch_path, held_kernel):
        assert th.allclose(costs, module, atol=1e-4, rtol=1e-5), (costs - module).abs().max()


@pytest.mark.parametrize("reward_form", ["logit", "softplus", "capped"])
def test_kernel_ensemble_costs_in_each_reward_form_match_the_torch_path_and_the_module(reward_form):
    members = ensemble_members([14, 17, 6])
    states = rolled_out_states(horizon=4, n_envs=3, n_samples=67, state_dim=7, feature_major=True)

    def combined_logits() -> th.Tensor:
        logits = th.stack([member(th.cat([states[:-1], states[1:]], dim=-1))[..., 0] for member in members])
        return logits.mean(dim=0) - 0.5 * logits.std(dim=0, unbiased=False)

    combined = spread_logits([member[-1] for member in members], combined_logits)
    module = marked_up_rewards(combined, reward_form, -0.3)
    kernel = ensemble_costs(members, states, 0.5, True, reward_form, -0.3)
    torch_path = ensemble_costs(members, states, 0.5, False, reward_form, -0.3)
    for costs in (kernel, torch_path):
        assert th.allclose(costs, module, atol=1e-4, rtol=1e-5), (costs - module).abs().max()


def test_kernel_values_with_held_state_dims_match_the_module():
    network = nn.Sequential(nn.Linear(7, 32), nn.ReLU(), nn.Linear(32, 1)).eval()
    value = fused.FusedValue(fused.freeze_mlp(network))
    states, initial_states = held_rolled_out_states([0, 3])
    value.hold([0, 3], initial_states)
    with th.no_grad():
        assert th.allclose(value(states[-1], fused.Workspace()), network(states[-1])[..., 0], atol=1e-5, rtol=1e-5)


def test_kernel_values_match_the_module():
    network = nn.Sequential(nn.Linear(12, 32), nn.LeakyReLU(), nn.Linear(32, 32), nn.LeakyReLU(), nn.Linear(32, 1)).eval()
    value = fused.FusedValue(fused.freeze_mlp(network))
    assert value.native is not None
    states = th.randn(5, 700, 12)
    with th.no_grad():
        assert th.allclose(value(states, fused.Workspace()), network(states)[..., 0], atol=1e-5, rtol=1e-5)


def test_kernel_costs_do_not_depend_on_the_thread_count():
    # 8 x 512 columns: enough for the kernel to split them between threads
    mlp = frozen_network([nn.Linear(24, 32), nn.LeakyReLU(), nn.Linear(32, 32), nn.LeakyReLU(), nn.Linear(32, 1)])
    states = rolled_out_states(horizon=10, n_envs=8, n_samples=512, state_dim=12, feature_major=True)
    threads = th.get_num_threads()
    try:
        th.set_num_threads(1)
        one_thread = transition_costs(mlp, states, True)
        th.set_num_threads(2)
        two_threads = transition_costs(mlp, states, True)
    finally:
        th.set_num_threads(threads)
    assert th.equal(one_thread, two_threads)
    members = ensemble_members([24, 32, 32])
    try:
        th.set_num_threads(1)
        one_thread = ensemble_costs(members, states, 1.0, True)
        th.set_num_threads(2)
        two_threads = ensemble_costs(members, states, 1.0, True)
    finally:
        th.set_num_threads(threads)
    assert th.equal(one_thread, two_threads)


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="x86 instruction sets")
def test_the_kernel_built_without_avx512_gives_the_same_costs(fresh_build, monkeypatch):
    # 8-float vectors instead of 16, as on CPUs without AVX-512 (most AMD ones before Zen 4)
    flags = tuple(flag for flag in native.COMPILER_FLAGS if flag != "-march=native") + ("-mavx2", "-mfma")
    monkeypatch.setattr(native, "COMPILER_FLAGS", flags)
    mlp = frozen_network([nn.Linear(14, 17), nn.LeakyReLU(0.2), nn.Linear(17, 6), nn.Tanh(), nn.Linear(6, 1)])
    states, initial_states = held_rolled_out_states([1, 4, 5])
    kernel, torch_path = transition_costs(mlp, states, True), transition_costs(mlp, states, False)
    assert th.allclose(kernel, torch_path, atol=1e-5, rtol=1e-5), (kernel - torch_path).abs().max()
    cost = fused.FusedTransitionCost(mlp, 7)
    cost.hold([1, 4, 5], initial_states)
    with th.no_grad():
        held = cost(states, 1.01 ** th.arange(4, dtype=th.float32), fused.Workspace())
    assert th.allclose(held, torch_path, atol=1e-5, rtol=1e-5), (held - torch_path).abs().max()
    members = ensemble_members([14, 17, 6])
    kernel, torch_path = ensemble_costs(members, states, 1.0, True), ensemble_costs(members, states, 1.0, False)
    assert th.allclose(kernel, torch_path, atol=1e-5, rtol=1e-5), (kernel - torch_path).abs().max()


def test_the_kernel_refuses_tensors_it_would_read_or_write_out_of_bounds():
    mlp = fused.native_mlp(frozen_network([nn.Linear(8, 16), nn.ReLU(), nn.Linear(16, 1)]))
    states, markups, out = th.randn(3, 10, 4), th.ones(2), th.empty(10)
    assert mlp.marked_up_sums(states, markups, True, out) is out
    bad_calls = {
        "out too short": (states, markups, True, th.empty(9)),
        "out strided": (states, markups, True, th.empty(20)[::2]),
        "markups for another horizon": (states, th.ones(3), True, out),
        "states of another size": (th.randn(3, 10, 5), markups, True, out),
        "float64 states": (states.double(), markups, True, out),
    }
    for name, arguments in bad_calls.items():
        with pytest.raises(ValueError):
            mlp.marked_up_sums(*arguments)
            pytest.fail(name)
    held = mlp.hold([1], th.randn(5, 4), pairs=True)
    assert mlp.marked_up_sums(states, markups, True, out, held) is out
    other_mlp = fused.native_mlp(frozen_network([nn.Linear(8, 4), nn.ReLU(), nn.Linear(4, 1)]))
    bad_holds = {
        "columns that do not split into the envs": (th.randn(3, 12, 4), markups, True, th.empty(12), held),
        "held inputs of another MLP": (states, markups, True, out, other_mlp.hold([1], th.randn(5, 4), pairs=True)),
    }
    for name, arguments in bad_holds.items():
        with pytest.raises(ValueError):
            mlp.marked_up_sums(*arguments)
            pytest.fail(name)
    with pytest.raises(ValueError, match="out of range"):
        mlp.hold([4], th.randn(5, 4), pairs=True)


@pytest.mark.parametrize(
    "layers",
    [
        [nn.Linear(24, 300), nn.ReLU(), nn.Linear(300, 1)],  # wider than the kernel's scratch arrays
        [nn.Linear(24, 8), nn.ELU(), nn.Linear(8, 1)],  # an activation the kernel does not know (nor the fused path)
    ],
)
def test_networks_the_kernel_cannot_take_keep_the_torch_path(layers):
    mlp = fused.freeze_mlp(nn.Sequential(*layers).eval())
    assert mlp is None or fused.native_mlp(mlp) is None


def test_float64_networks_keep_the_torch_path():
    network = nn.Sequential(nn.Linear(8, 16), nn.ReLU(), nn.Linear(16, 1)).double().eval()
    assert fused.native_mlp(fused.freeze_mlp(network)) is None


@pytest.fixture
def fresh_build(monkeypatch, tmp_path):
    """An empty kernel cache, and ``load_library`` forgetting the library it loaded."""
    monkeypatch.setenv("SB3_MPAIL_CACHE", str(tmp_path))
    native.load_library.cache_clear()
    yield tmp_path
    native.load_library.cache_clear()


def test_the_library_is_built_once_and_then_taken_from_the_cache(fresh_build, monkeypatch):
    library = native._build(native._compiler())
    assert library.parent == fresh_build and list(fresh_build.iterdir()) == [library]

    def no_compiler(*args, **kwargs):
        raise AssertionError("compiled again")

    monkeypatch.setattr(native.subprocess, "run", no_compiler)
    assert native._build(native._compiler()) == library


def test_a_failed_build_warns_leaves_no_file_and_keeps_the_torch_path(fresh_build, monkeypatch):
    monkeypatch.setattr(native, "COMPILER_FLAGS", native.COMPILER_FLAGS + ("-fno-such-flag",))
    with pytest.warns(UserWarning, match="kernel is unavailable.*-fno-such-flag"):
        assert native.load_library() is None
    assert list(Path(fresh_build).iterdir()) == []  # no partial library for a later process to load
    mlp = frozen_network([nn.Linear(8, 16), nn.ReLU(), nn.Linear(16, 1)])
    assert fused.FusedTransitionCost(mlp, 4).native is None


def test_without_a_compiler_the_planner_warns_and_keeps_the_torch_path(fresh_build, monkeypatch):
    monkeypatch.setattr(native, "_compiler", lambda: None)
    with pytest.warns(UserWarning, match="no C compiler"):
        assert native.load_library() is None


def test_the_kernel_can_be_switched_off(fresh_build, monkeypatch):
    monkeypatch.setenv("SB3_MPAIL_NATIVE", "0")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert native.load_library() is None
    assert list(Path(fresh_build).iterdir()) == []


def test_the_planner_kernel_reads_only_the_state_dims_the_bicycle_moves():
    from sb3_mpail.envs.navigation import NavigationEnv
    from sb3_mpail.policies import MPPIPolicy

    env = NavigationEnv()
    policy = MPPIPolicy(env.observation_space, env.action_space, dynamics="bicycle")
    policy.set_training_mode(False)
    with th.no_grad():
        cost = policy.planner.trajectory_cost(th.randn(2, 12), horizon=10)
    moving = [0, 1, 5, 6, 7, 11]  # x, y, yaw, vx, vy, wz: the held ones are folded into a bias per env
    assert list(cost.fused_step_cost._held.read) == moving + [12 + dim for dim in moving]
    assert list(cost.fused_value._held.read) == moving
