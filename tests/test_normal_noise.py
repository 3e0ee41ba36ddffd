"""The sampling noise's kernel (sb3_mpail/mppi/normal_noise.c): torch.randn's numbers, bit for bit, or torch.randn itself."""

import math
import platform

import pytest
import torch as th

import sb3_mpail.mppi.native as native
from sb3_mpail.mppi.sampling import GaussianSampler

CPU = th.device("cpu")


@pytest.fixture
def fresh_check():
    """``_normal_fill`` forgetting the result of its check against torch."""
    native._normal_fill.cache_clear()
    yield
    native._normal_fill.cache_clear()


def _generator_part_way() -> th.Generator:
    generator = th.Generator().manual_seed(7)
    th.randn(3, generator=generator)  # torch's path below 16 numbers, which keeps a spare normal in the generator
    th.rand(500, generator=generator)  # part-way through the twister's 624 words
    return generator


def _bits(tensor: th.Tensor) -> th.Tensor:
    return tensor.view(th.int32)


def test_the_noise_kernel_is_used_where_torch_takes_its_avx2_normal_kernel():
    expected = (
        platform.machine() in ("x86_64", "AMD64")
        and th.backends.cpu.get_cpu_capability() in ("AVX2", "AVX512")
        and {"avx2", "fma"} <= set(native._cpu_description().split())  # the CPU's flags, as the build keys on
        and native.load_library() is not None
    )
    assert (native._normal_fill() is not None) == expected


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("shape", [(16,), (17,), (31,), (624,), (625,), (3, 7, 59), (10, 2, 512, 2), (1, 65541)])
def test_the_noise_is_torch_randn_bit_for_bit_and_leaves_the_generator_as_torch_does(shape, threads):
    generator, twin = _generator_part_way(), _generator_part_way()
    previous_threads = th.get_num_threads()
    try:
        th.set_num_threads(threads)
        drawn = native.standard_normal(shape, generator, CPU, th.float32)
    finally:
        th.set_num_threads(previous_threads)
    expected = th.randn(shape, generator=twin)
    assert drawn.shape == expected.shape and drawn.dtype == th.float32
    assert th.equal(_bits(drawn), _bits(expected))
    assert th.equal(generator.get_state(), twin.get_state())
    # the spare normal torch keeps for short draws is still there, and the twister goes on where torch's does
    assert th.equal(th.randn(5, generator=generator), th.randn(5, generator=twin))
    assert th.equal(th.randn(1000, generator=generator), th.randn(1000, generator=twin))


def test_without_a_generator_the_noise_comes_from_torch_default_one():
    th.manual_seed(11)
    drawn = native.standard_normal((40, 9), None, CPU, th.float32)
    th.manual_seed(11)
    assert th.equal(_bits(drawn), _bits(th.randn(40, 9)))


def test_float64_noise_is_torch_randn():
    drawn = native.standard_normal((64, 3), th.Generator().manual_seed(2), CPU, th.float64)
    assert drawn.dtype == th.float64
    assert th.equal(drawn, th.randn(64, 3, generator=th.Generator().manual_seed(2), dtype=th.float64))


def test_the_sampler_draws_torch_randn_noise():
    sampler = GaussianSampler([-1.0, -2.0], [1.0, 2.0], noise_std=0.3)
    plan = th.zeros(3, 10, 2)
    actions = sampler(plan, 64, th.Generator().manual_seed(5))
    noise = th.randn(10, 3, 64, 2, generator=th.Generator().manual_seed(5))
    expected = th.clamp(noise * sampler.noise_std, sampler.action_low, sampler.action_high)
    assert th.equal(actions, expected)


def test_where_the_kernel_does_not_reproduce_torch_it_warns_and_keeps_torch_randn(fresh_check, monkeypatch):
    if native.load_library() is None or not hasattr(native.load_library(), "standard_normal_fill"):
        pytest.skip("no noise kernel to check on this machine")
    torch_randn = th.randn

    def last_bit_off(*args, **kwargs):  # a torch whose Box-Muller rounds differently
        return th.nextafter(torch_randn(*args, **kwargs), th.tensor(math.inf))

    monkeypatch.setattr(th, "randn", last_bit_off)
    with pytest.warns(UserWarning, match="does not reproduce torch.randn"):
        assert native._normal_fill() is None
    drawn = native.standard_normal((100,), th.Generator().manual_seed(3), CPU, th.float32)
    assert th.equal(drawn, last_bit_off(100, generator=th.Generator().manual_seed(3)))


def test_where_torch_takes_another_normal_kernel_the_noise_is_torch_randn(fresh_check, monkeypatch):
    monkeypatch.setattr(th.backends.cpu, "get_cpu_capability", lambda: "DEFAULT")
    assert native._normal_fill() is None
    drawn = native.standard_normal((100,), th.Generator().manual_seed(3), CPU, th.float32)
    assert th.equal(drawn, th.randn(100, generator=th.Generator().manual_seed(3)))
