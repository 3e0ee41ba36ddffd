"""The optimised planner computes the same plans as the plain reference implementation (paper Alg. 2 as written)."""

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest
import torch as th

import sb3_mpail.mppi.fused as fused
from sb3_mpail.envs.navigation import NavigationEnv
from sb3_mpail.mppi import AngleFeatures, KinematicBicycle, PendulumDynamics, ensemble
from sb3_mpail.mppi.costs import MappedView
from sb3_mpail.mppi.dynamics import LearnedDynamics
from sb3_mpail.mppi.ensemble import FrozenEnsembleCost
from sb3_mpail.mppi.fused import freeze_mlp
from sb3_mpail.mppi.planner import rollout
from sb3_mpail.mppi.reference import rollout as rollout_step_by_step
from sb3_mpail.policies import MPPIPolicy

NAVIGATION = NavigationEnv()
PENDULUM = gym.make("Pendulum-v1")


def make_policy(env: gym.Env, dynamics: str, seed: int = 0, dtype: th.dtype = th.float64, **kwargs) -> MPPIPolicy:
    """
    A policy with its real discriminator and value. Equivalence is checked in float64 by default: the weights
    ``exp(-C / temperature)`` amplify the float32 rounding of the costs by ``1 / temperature``, which would blur the
    check; float32 is checked separately at the paper's settings.
    """
    th.manual_seed(seed)
    policy = MPPIPolicy(env.observation_space, env.action_space, dynamics=dynamics, **kwargs).to(dtype)
    # a few training-mode calls move spectral norm's power-iteration vectors away from their initial values
    with th.no_grad():
        states, next_states = th.randn(2, 64, env.observation_space.shape[0], dtype=dtype)
        for _ in range(3):
            policy.discriminator(policy.features(states), None, policy.features(next_states), None)
    policy.set_training_mode(False)
    policy.temperature.fill_(0.05)  # peaked weights make the plan sensitive to every cost
    return policy


def navigation_states(n_envs: int, seed: int = 1, dtype: th.dtype = th.float64) -> th.Tensor:
    generator = th.Generator().manual_seed(seed)
    states = th.randn(n_envs, 12, generator=generator) * th.tensor([3, 3, 0.05, 0.1, 0.1, 2, 1, 0.2, 0.1, 0.2, 0.2, 1])
    states[:, 5] = th.remainder(states[:, 5] + np.pi, 2 * np.pi) - np.pi
    return states.to(dtype)


def pendulum_states(n_envs: int, seed: int = 1, dtype: th.dtype = th.float64) -> th.Tensor:
    generator = th.Generator().manual_seed(seed)
    angles = th.rand(n_envs, generator=generator) * 2 * np.pi - np.pi
    return th.stack((th.cos(angles), th.sin(angles), th.randn(n_envs, generator=generator) * 3), dim=1).to(dtype)


def plan_both_ways(policy: MPPIPolicy, states: th.Tensor, n_steps: int = 3, seed: int = 0):
    """Runs ``n_steps`` warm-started planning steps with the optimised and the reference planner, same noise."""
    planner = policy.planner
    results = []
    for planning_step in (planner.forward, planner.reference_forward):
        generator = th.Generator().manual_seed(seed)
        plan = planner.initial_plan(states.shape[0])
        steps = []
        with th.no_grad():
            for _ in range(n_steps):
                plan, action_std = planning_step(states, plan, policy.temperature, generator)
                steps.append((plan.clone(), action_std.clone()))
        results.append(steps)
    return results


def assert_same_plans(optimised, reference, atol=1e-9):
    for (plan, action_std), (reference_plan, reference_std) in zip(optimised, reference):
        assert th.allclose(plan, reference_plan, atol=atol, rtol=0), (plan - reference_plan).abs().max()
        assert th.allclose(action_std, reference_std, atol=atol, rtol=0), (action_std - reference_std).abs().max()


@pytest.mark.parametrize("n_envs", [1, 5])
def test_bicycle_plans_match_the_reference(n_envs):
    policy = make_policy(NAVIGATION, "bicycle", n_samples=256)
    optimised, reference = plan_both_ways(policy, navigation_states(n_envs))
    assert_same_plans(optimised, reference)
    assert th.all(optimised[-1][1] > 0.01)  # the weights are not degenerate: the comparison is not vacuous


def use_cpu_path(monkeypatch: pytest.MonkeyPatch, path: str) -> None:
    """
    The compiled kernel where it builds ("kernel"), or the torch path with oneDNN's fused linear on every hidden
    layer ("onednn") or on none ("blas", the path of GPUs and builds without oneDNN).
    """
    if path == "kernel":
        return
    monkeypatch.setattr(fused, "native_mlp", lambda mlp: None)
    if path == "onednn":
        monkeypatch.setattr(fused, "ONEDNN_MIN_ROWS_PER_THREAD", 1)
    else:
        monkeypatch.setattr(fused, "ONEDNN_LINEAR", None)


@pytest.mark.parametrize("cpu_path", ["kernel", "onednn", "blas"])
def test_float32_plans_at_the_paper_settings_match_the_reference(monkeypatch, cpu_path):
    use_cpu_path(monkeypatch, cpu_path)
    policy = make_policy(NAVIGATION, "bicycle", dtype=th.float32)  # N = 512, H = 10, J = 5
    policy.temperature.fill_(1.0)
    assert_same_plans(*plan_both_ways(policy, navigation_states(4, dtype=th.float32)), atol=1e-5)


def test_pendulum_plans_match_the_reference():
    policy = make_policy(PENDULUM, "pendulum", n_samples=256, horizon=15)
    assert_same_plans(*plan_both_ways(policy, pendulum_states(4)))


@pytest.mark.parametrize("cpu_path", ["kernel", "blas"])
def test_feature_maps_go_through_the_fused_views_and_match_the_reference(monkeypatch, cpu_path):
    use_cpu_path(monkeypatch, cpu_path)
    headings = AngleFeatures([5])
    policy = make_policy(NAVIGATION, "bicycle", n_samples=128, discriminator_features=headings, value_features=headings)
    with th.no_grad():
        assert isinstance(policy.planner.step_cost.planning_view(12), MappedView)
        assert isinstance(policy.planner.terminal_value.planning_view(12), MappedView)
    assert_same_plans(*plan_both_ways(policy, navigation_states(3)))
    float32 = make_policy(NAVIGATION, "bicycle", dtype=th.float32, n_samples=128, discriminator_features=headings,
                          value_features=headings)  # fmt: skip
    float32.temperature.fill_(1.0)
    assert_same_plans(*plan_both_ways(float32, navigation_states(4, dtype=th.float32)), atol=1e-5)


def test_delta_sampling_plans_match_the_reference():
    policy = make_policy(NAVIGATION, "bicycle", n_samples=128, sampler="delta", noise_std=[1.0, 0.5])
    assert_same_plans(*plan_both_ways(policy, navigation_states(3)))


@pytest.mark.parametrize("switches", [dict(use_terminal_value=False), dict(use_step_cost=False)])
def test_ablations_match_the_reference(switches):
    policy = make_policy(NAVIGATION, "bicycle", n_samples=128, **switches)
    assert_same_plans(*plan_both_ways(policy, navigation_states(3)))


@pytest.mark.parametrize(
    "network_kwargs",
    [
        dict(discriminator_hidden_sizes=(), value_hidden_sizes=()),
        dict(discriminator_hidden_sizes=(16, 8, 8), use_spectral_norm=False),
    ],
)
def test_other_network_shapes_match_the_reference(network_kwargs):
    policy = make_policy(NAVIGATION, "bicycle", n_samples=128, **network_kwargs)
    assert_same_plans(*plan_both_ways(policy, navigation_states(2)))


@pytest.mark.parametrize("chunk_rows", [250, 700, 2000])
def test_cache_sized_chunks_match_the_reference(monkeypatch, chunk_rows):
    # 3 envs x 200 samples = 600 columns per step: 250 makes column blocks with a partial last one, 700 one step per
    # chunk, 2000 three steps per chunk with a partial last one
    monkeypatch.setattr(fused, "chunk_rows", lambda: chunk_rows)
    policy = make_policy(NAVIGATION, "bicycle", n_samples=200)
    assert_same_plans(*plan_both_ways(policy, navigation_states(3)))


def test_torch_builds_with_onednn_give_the_fused_linear():
    # the op is private to torch: a torch upgrade that drops it must fail here rather than silently plan slower
    assert (fused.ONEDNN_LINEAR is not None) == th.backends.mkldnn.is_available()


@pytest.mark.parametrize("activation", [th.nn.ReLU(), th.nn.LeakyReLU(0.2), th.nn.Tanh()])
@pytest.mark.parametrize("cpu_path", ["kernel", "onednn", "blas"])
def test_frozen_hidden_layers_match_the_module(monkeypatch, activation, cpu_path):
    use_cpu_path(monkeypatch, cpu_path)
    th.manual_seed(0)
    network = th.nn.Sequential(th.nn.Linear(5, 16), activation, th.nn.Linear(16, 8), activation, th.nn.Linear(8, 1)).eval()
    inputs = th.randn(300, 5)
    frozen = fused.freeze_mlp(network)
    with th.no_grad():
        values = fused.FusedValue(frozen)(inputs, fused.Workspace())
        assert th.allclose(values, network(inputs)[:, 0], atol=1e-5, rtol=0)


def test_fused_views_are_used_only_when_planning():
    policy = make_policy(NAVIGATION, "bicycle")
    step_cost, value = policy.planner.step_cost, policy.planner.terminal_value
    with th.no_grad():
        assert step_cost.planning_view(12) is not None and value.planning_view(12) is not None
        policy.set_training_mode(True)  # spectral norm's power iteration must keep running on every call
        assert step_cost.planning_view(12) is None and value.planning_view(12) is None
    policy.set_training_mode(False)
    assert step_cost.planning_view(12) is None and value.planning_view(12) is None  # gradients enabled


def view_costs(step_cost, value, states: th.Tensor) -> tuple:
    """Step costs of consecutive states and values through the planning views, and through the modules."""
    rolled_out = states.view(4, 1, 4, 12)
    markups = th.ones(3, dtype=states.dtype)
    with th.no_grad():
        step_view, value_view = step_cost.planning_view(12), value.planning_view(12)
        fused_costs = step_view(rolled_out, markups, fused.Workspace()).clone()
        fused_values = value_view(states, fused.Workspace()).clone()
        module_costs = step_cost(rolled_out[:-1], rolled_out[1:]).sum(0)
        module_values = value(states)
    return (step_view, value_view), (fused_costs, fused_values), (module_costs, module_values)


def test_planning_views_are_reused_until_the_networks_change():
    policy = make_policy(NAVIGATION, "bicycle")
    step_cost, value = policy.planner.step_cost, policy.planner.terminal_value
    states = navigation_states(16)
    views, _, _ = view_costs(step_cost, value, states)
    assert view_costs(step_cost, value, states)[0] == views  # nothing changed: the same frozen weights
    discriminator, value_net = step_cost.discriminator, value.value_network
    optimizer = th.optim.SGD([*discriminator.parameters(), *value_net.parameters()], lr=0.5)
    changes = {
        "an optimiser step": lambda: optimizer.step(),
        "load_state_dict": lambda: (
            discriminator.load_state_dict({k: v + 0.1 for k, v in discriminator.state_dict().items()}),
            value_net.load_state_dict({k: v * 0.9 for k, v in value_net.state_dict().items()}),
        ),
        "tensors swapped through .data": lambda: [
            setattr(parameter, "data", parameter.data * 1.1)
            for parameter in (*discriminator.parameters(), *value_net.parameters())
        ],
    }
    for name, change in changes.items():
        for parameter in (*discriminator.parameters(), *value_net.parameters()):
            parameter.grad = th.ones_like(parameter)
        before = view_costs(step_cost, value, states)
        change()
        new_views, fused_results, module_results = view_costs(step_cost, value, states)
        assert all(new is not old for new, old in zip(new_views, before[0])), name
        assert not th.allclose(fused_results[0], before[1][0]), name  # the change moved the costs...
        for fused_result, module_result in zip(fused_results, module_results):  # ...and the views followed
            assert th.allclose(fused_result, module_result, atol=1e-9, rtol=0), name


def test_copies_of_costs_with_planning_views_rebuild_their_own():
    policy = make_policy(NAVIGATION, "bicycle", dtype=th.float32)
    step_cost, value = policy.planner.step_cost, policy.planner.terminal_value
    states = navigation_states(16, dtype=th.float32)
    views, _, _ = view_costs(step_cost, value, states)
    assert views[0].native is not None or fused.native_mlp(views[0].mlp) is None  # the kernel's view (pointers)
    # spectral-normed modules pickle only through their state_dict: the discriminator's cost is deep-copied only
    for copy_of_value in (copy.deepcopy, lambda module: pickle.loads(pickle.dumps(module))):
        step_copy, value_copy = copy.deepcopy(step_cost), copy_of_value(value)
        copied_views, fused_results, module_results = view_costs(step_copy, value_copy, states)
        assert copied_views[0] is not views[0] and copied_views[1] is not views[1]
        for fused_result, module_result in zip(fused_results, module_results):
            assert th.allclose(fused_result, module_result, atol=1e-4, rtol=1e-4)


def test_planning_with_gradients_enabled_matches_the_reference():
    policy = make_policy(NAVIGATION, "bicycle", n_samples=64)
    states, planner = navigation_states(2), policy.planner
    plan = planner(states, planner.initial_plan(2), policy.temperature, th.Generator().manual_seed(0)).plan
    with th.no_grad():
        generator = th.Generator().manual_seed(0)
        expected = planner.reference_forward(states, planner.initial_plan(2), policy.temperature, generator)
    assert th.allclose(plan.detach(), expected.plan, atol=1e-9, rtol=0)


@pytest.mark.parametrize(
    "model, states", [(KinematicBicycle(), navigation_states(3)), (PendulumDynamics(), pendulum_states(3))]
)
def test_batched_rollouts_match_step_by_step_rollouts(model, states):
    generator = th.Generator().manual_seed(2)
    action_dim = 2 if isinstance(model, KinematicBicycle) else 1
    actions = th.rand(20, states.shape[0], 7, action_dim, generator=generator, dtype=states.dtype) * 2 - 1
    if isinstance(model, PendulumDynamics):
        actions = actions * 3  # beyond the torque limit, so the clamp is exercised
    batched = rollout(model, states, actions)
    step_by_step = rollout_step_by_step(model, states, actions)
    assert batched.shape == step_by_step.shape
    assert th.equal(batched[0], step_by_step[0].contiguous())
    assert th.allclose(batched, step_by_step, atol=1e-10, rtol=0)


@pytest.mark.parametrize("hidden_sizes", [(32, 32, 32), (8,), ()])
def test_a_learned_models_batched_rollout_matches_its_step_by_step_forward(hidden_sizes):
    rng = np.random.default_rng(0)
    states = rng.normal(3.0, 2.0, size=(400, 4)).astype(np.float32)  # normalisations far from the identity
    actions = rng.uniform(-1, 1, size=(400, 2)).astype(np.float32)
    model = LearnedDynamics(4, 2, hidden_sizes=hidden_sizes, n_epochs=2, seed=0)
    model.fit(states, actions, 0.9 * states + np.repeat(actions, 2, axis=1))
    initial_states = th.as_tensor(states[:3])
    sequences = th.as_tensor(rng.uniform(-1, 1, size=(6, 3, 5, 2)).astype(np.float32))
    with th.no_grad():
        batched = rollout(model, initial_states, sequences)
        step_by_step = rollout_step_by_step(model, initial_states, sequences)
    assert batched.shape == step_by_step.shape == (7, 3, 5, 4)
    assert th.allclose(batched, step_by_step, atol=1e-5, rtol=1e-5)


def test_compiled_planner_matches_the_eager_one():
    if not hasattr(th, "compile"):
        pytest.skip("torch.compile is unavailable")
    policy = make_policy(PENDULUM, "pendulum", n_samples=32, horizon=4, n_iterations=2, compile_planner=True)
    try:
        optimised, reference = plan_both_ways(policy, pendulum_states(2), n_steps=3)
    except Exception as error:
        if not type(error).__module__.startswith(("torch._dynamo", "torch._inductor")):
            raise
        pytest.skip(f"torch.compile does not work on this machine (no C++ toolchain?): {type(error).__name__}")
    assert_same_plans(optimised, reference)


@pytest.mark.parametrize("features, chunk_rows", [(None, None), ({"angles": [5]}, None), (None, 700)])
def test_discriminator_ensembles_plan_through_their_batched_view_and_match_the_reference(features, chunk_rows, monkeypatch):
    if chunk_rows is not None:  # chunks of 350 rows, not whole time steps (192 rows each)
        monkeypatch.setattr(ensemble, "chunk_rows", lambda: chunk_rows)
    policy = make_policy(NAVIGATION, "bicycle", n_samples=64, discriminator_ensemble_size=3, discriminator_disagreement=1.5,
                         discriminator_features=features)  # fmt: skip
    with th.no_grad():
        view = policy.planner.step_cost.planning_view(12)
    assert isinstance(view.view if isinstance(view, MappedView) else view, FrozenEnsembleCost)
    optimised, reference = plan_both_ways(policy, navigation_states(3))
    assert_same_plans(optimised, reference)


def test_ensembles_of_members_with_different_layers_plan_through_the_module_path():
    members = [th.nn.Sequential(th.nn.Linear(24, width), th.nn.ReLU(), th.nn.Linear(width, 1)).eval() for width in (32, 16)]
    assert FrozenEnsembleCost.build([freeze_mlp(member) for member in members], 12, 1.0) is None
    assert FrozenEnsembleCost.build([freeze_mlp(members[0])] * 2, 12, 1.0) is not None
    linear = th.nn.Sequential(th.nn.Linear(24, 1)).eval()  # no hidden layer
    assert FrozenEnsembleCost.build([freeze_mlp(linear)] * 2, 12, 1.0) is None
