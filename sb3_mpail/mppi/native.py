"""
The planner's CPU kernels, in C beside this module:

- ``mlp_cost.c``: a small MLP's cost over many rows in one pass. The torch path of :mod:`sb3_mpail.mppi.fused` runs
  each layer as a matrix product over a chunk of rows and then adds the bias and activation in passes of their own, so
  every layer's output goes to memory and back. The kernel instead runs every layer for a block of rows while it is in
  the L1 cache and sums the marked-up outputs over the horizon (``BENCHMARKS.md``, "planner_speed", times the planner
  with and without it).
- ``normal_noise.c``: ``torch.randn``'s CPU float32 numbers, the same bit for bit, drawn 4 to 6 times faster (1 and 2
  threads; :func:`standard_normal`): torch draws each uniform through a function call on one thread.

They are compiled at first use with the machine's C compiler (``$CC``, else ``cc``, ``gcc`` or ``clang``) for the
machine's own instruction set and linked to the GNU OpenMP runtime torch has loaded, so their threads are torch's
(as many as ``torch.get_num_threads()``). The library is cached under ``$SB3_MPAIL_CACHE`` (default
``~/.cache/sb3_mpail``), one file per version of the sources, compiler, flags, OpenMP runtime and CPU. Without a
compiler or that runtime (torch builds for macOS use another), or with ``SB3_MPAIL_NATIVE=0``, the planner keeps the
torch path (a warning says why, once); the two agree to float rounding, and draw the same noise.
"""

import ctypes
import hashlib
import math
import os
import platform
import shutil
import subprocess
import tempfile
import warnings
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Callable, List, Optional, Sequence, Tuple

import torch as th

#: the kernels' sources, each with the flags it needs beyond ``COMPILER_FLAGS``
SOURCES = {
    Path(__file__).with_name("mlp_cost.c"): (),
    # torch's noise bit for bit: fused multiply-adds only where the source writes them, as torch's build has them
    Path(__file__).with_name("normal_noise.c"): ("-ffp-contract=off",),
}
COMPILER_FLAGS = ("-O3", "-march=native", "-fno-strict-aliasing", "-fPIC", "-fopenmp")
#: activation codes of ``mlp_cost.c``, by the fused paths' oneDNN names
ACTIVATION_CODES = {"relu": 1, "leaky_relu": 2, "tanh": 3}
#: codes of ``mlp_cost.c``'s output forms, by the names of :data:`~sb3_mpail.mppi.reward_forms.REWARD_FORMS`
FORM_CODES = {"logit": 0, "softplus": 1, "capped": 2}


def _compiler() -> Optional[str]:
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        path = shutil.which(name) if name else None
        if path is not None:
            return path
    return None


def _cpu_description() -> str:
    """What the library is built for: ``-march=native`` code may not run on another CPU sharing the cache."""
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            flags = next((line for line in cpuinfo if line.startswith(("flags", "Features"))), "")
    except OSError:
        flags = ""
    return f"{platform.machine()} {platform.processor()} {flags}"


def _openmp_runtime() -> Path:
    """
    The GNU OpenMP library torch uses, as loaded in this process: the copy inside torch's package (pip wheels), else
    the system's ``libgomp.so.1``. Other packages may load copies of their own, which torch does not use.
    """
    try:
        with open("/proc/self/maps") as maps:
            loaded = {Path(line.split(maxsplit=5)[-1].strip()) for line in maps if "libgomp" in line}
    except OSError:
        loaded = set()
    torch_directory = Path(th.__file__).resolve().parent
    for candidates in (
        [path for path in loaded if path.resolve().is_relative_to(torch_directory)],
        [path for path in loaded if path.name == "libgomp.so.1"],
    ):
        if len(candidates) == 1:
            return candidates[0]
    raise RuntimeError(f"torch's GNU OpenMP runtime (libgomp) is not among those loaded: {sorted(map(str, loaded))}")


def _cache_directory() -> Path:
    return Path(os.environ.get("SB3_MPAIL_CACHE", Path.home() / ".cache" / "sb3_mpail"))


def _build(compiler: str) -> Path:
    """Compiles the kernels unless the cache has them; the library appears whole or not at all (an atomic rename)."""
    openmp = _openmp_runtime()
    source_flags = [flag for flags in SOURCES.values() for flag in flags]
    text = [compiler, *COMPILER_FLAGS, *source_flags, str(openmp), _cpu_description()]
    key = hashlib.sha256(b"\0".join([*(source.read_bytes() for source in SOURCES), *(part.encode() for part in text)]))
    directory = _cache_directory()
    library = directory / f"mppi_kernels-{key.hexdigest()[:16]}.so"
    if library.exists():
        return library
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=directory) as build_directory:
        built = Path(build_directory) / library.name
        objects = {source: Path(build_directory) / source.with_suffix(".o").name for source in SOURCES}
        compile_commands = [
            [compiler, *COMPILER_FLAGS, *flags, "-c", str(source), "-o", str(objects[source])]
            for source, flags in SOURCES.items()
        ]
        # linked to torch's OpenMP file itself (not -fopenmp's -lgomp, which may name another copy of the runtime)
        link_command = [compiler, "-shared", *map(str, objects.values()), str(openmp), "-lm", "-o", str(built)]
        for command in (*compile_commands, link_command):
            result = subprocess.run(command, capture_output=True, text=True, timeout=120)
            if result.returncode != 0:
                raise RuntimeError(f"{' '.join(command)} failed: {result.stderr.strip()[-2000:]}")
        os.replace(built, library)
    return library


@cache
def load_library() -> Optional[ctypes.CDLL]:
    """
    The compiled kernel, built on first use, or ``None`` (with a warning) where it cannot be built or loaded, or is
    switched off with ``SB3_MPAIL_NATIVE=0``.
    """
    if os.environ.get("SB3_MPAIL_NATIVE", "1") == "0":
        return None
    compiler = _compiler()
    if compiler is None:
        warnings.warn("sb3_mpail: no C compiler found (set CC); the planner takes its slower torch path", stacklevel=2)
        return None
    try:
        library = ctypes.CDLL(str(_build(compiler)))
    except (OSError, RuntimeError, subprocess.SubprocessError) as error:
        warnings.warn(f"sb3_mpail: the planner's CPU kernel is unavailable ({error}); using the torch path", stacklevel=2)
        return None
    library.mlp_max_width.restype = ctypes.c_int
    library.mlp_costs.restype = None
    pointer = ctypes.c_void_p
    library.mlp_costs.argtypes = [
        ctypes.POINTER(_Inputs), ctypes.POINTER(_Mlp), ctypes.c_int, pointer, pointer, pointer, ctypes.c_int
    ]  # fmt: skip
    library.ensemble_max_members.restype = ctypes.c_int
    library.ensemble_costs.restype = None
    library.ensemble_costs.argtypes = [
        ctypes.POINTER(_Inputs), pointer, ctypes.c_int, pointer, ctypes.c_float, ctypes.c_int, pointer, pointer, ctypes.c_int
    ]  # fmt: skip
    if hasattr(library, "standard_normal_fill"):  # built for CPUs with AVX2 and FMA only
        library.standard_normal_fill.restype = None
        library.standard_normal_fill.argtypes = [pointer, pointer, ctypes.c_long, ctypes.c_int]
    return library


class _Mlp(ctypes.Structure):
    """``struct mlp`` of ``mlp_cost.c``."""

    _fields_ = [
        ("n_layers", ctypes.c_int),
        ("widths", ctypes.c_void_p),
        ("weights", ctypes.c_void_p),
        ("biases", ctypes.c_void_p),
        ("activations", ctypes.c_void_p),
        ("slopes", ctypes.c_void_p),
    ]


class _Inputs(ctypes.Structure):
    """``struct inputs`` of ``mlp_cost.c``."""

    _fields_ = [
        ("states", ctypes.c_void_p),
        ("feature_stride", ctypes.c_long),
        ("time_stride", ctypes.c_long),
        ("column_stride", ctypes.c_long),
        ("state_dim", ctypes.c_int),
        ("pairs", ctypes.c_int),
        ("steps", ctypes.c_int),
        ("columns", ctypes.c_long),
        ("n_read", ctypes.c_int),
        ("read", ctypes.c_void_p),
        ("group_biases", ctypes.c_void_p),
        ("group_columns", ctypes.c_long),
    ]


@dataclass
class HeldInputs:
    """
    Inputs of the MLP that are constant within each group of consecutive columns (one group per env: state
    dimensions a roll-out holds at their initial values), folded into a first-layer bias per group.

    :param read: the inputs that are not held, which the kernel reads
    :param group_biases: per group, the first layer's bias plus the held inputs' terms, ``(groups, first width)``
    :param input_size: the MLP's number of inputs
    """

    read: "ctypes.Array[ctypes.c_int]"
    group_biases: th.Tensor
    input_size: int


class NativeMlp:
    """
    A frozen MLP (one output, no activation after it) evaluated by the compiled kernel, on CPU float32 tensors.
    Build it with :meth:`from_layers`, which returns ``None`` where the kernel cannot take the network.

    :param library: the loaded kernel
    :param weights: per layer, the weight ``(in, out)``, contiguous float32
    :param biases: per layer, the bias ``(out,)``
    :param activation_codes: per layer, the kernel's code of the activation after it (0: none)
    :param slopes: per layer, the negative slope of a leaky ReLU (else unused)
    """

    def __init__(
        self,
        library: ctypes.CDLL,
        weights: List[th.Tensor],
        biases: List[th.Tensor],
        activation_codes: List[int],
        slopes: List[float],
    ):
        self.library = library
        # kept alive: the kernel reads them through the pointers below (the output bias only for a nonlinear form)
        self.weights, self.biases, self.output_bias = weights, biases[:-1], biases[-1]
        n_layers = len(weights)
        self.input_size = weights[0].shape[0]
        self._widths = (ctypes.c_int * (n_layers + 1))(self.input_size, *[weight.shape[1] for weight in weights])
        self._weights = (ctypes.c_void_p * n_layers)(*[weight.data_ptr() for weight in weights])
        self._biases = (ctypes.c_void_p * n_layers)(*[bias.data_ptr() for bias in self.biases], None)
        self._activations = (ctypes.c_int * n_layers)(*activation_codes)
        self._slopes = (ctypes.c_float * n_layers)(*slopes)
        self._held_parts: dict = {}  # per (held dims, pairs): the inputs read and the held weight
        self._mlp = _Mlp(
            n_layers,
            ctypes.addressof(self._widths),
            ctypes.addressof(self._weights),
            ctypes.addressof(self._biases),
            ctypes.addressof(self._activations),
            ctypes.addressof(self._slopes),
        )

    @classmethod
    def from_layers(
        cls, weights: List[th.Tensor], biases: List[th.Tensor], activations: List[Optional[str]], slopes: List[float]
    ) -> Optional["NativeMlp"]:
        """
        :param weights: per layer, the weight ``(in, out)`` as the fused paths hold it
        :param biases: per layer, the bias ``(out,)``; the last layer's is left to the caller but for a nonlinear form
        :param activations: per layer, the oneDNN name of the activation after it, or ``None``
        :param slopes: per layer, the activation's first argument (a leaky ReLU's slope), else 0
        :return: the kernel's view of the MLP, or ``None`` where the kernel is unavailable or cannot take the MLP
            (not CPU float32, a layer wider than the kernel's limit, an activation it does not know, more than one
            output, an activation after the output)
        """
        library = load_library()
        if library is None or weights[-1].shape[1] != 1 or activations[-1] is not None:
            return None
        if any(weight.device.type != "cpu" or weight.dtype != th.float32 for weight in weights):
            return None
        if max(max(weight.shape) for weight in weights) > library.mlp_max_width():
            return None
        if any(name is not None and name not in ACTIVATION_CODES for name in activations):
            return None
        codes = [0 if name is None else ACTIVATION_CODES[name] for name in activations]
        return cls(
            library,
            [weight.contiguous() for weight in weights],
            [bias.contiguous() for bias in biases],
            codes,
            [float(slope) for slope in slopes],
        )

    def hold(self, held_dims: Sequence[int], initial_states: th.Tensor, pairs: bool) -> HeldInputs:
        """
        The MLP's inputs from state dimensions ``held_dims`` of ``initial_states``, folded into a first-layer bias per
        env, for :meth:`marked_up_sums` on roll-outs that keep those dimensions at their initial values.

        :param held_dims: the state dimensions held
        :param initial_states: ``(n_envs, state_dim)``, CPU float32
        :param pairs: whether the MLP's input is a transition ``[s, s']`` (both halves then hold)
        :return: what :meth:`marked_up_sums` takes as ``held``
        """
        state_dim = initial_states.shape[-1]
        _check_input_size(self.input_size, state_dim, pairs)
        dims = sorted(set(held_dims))
        if dims and not 0 <= dims[0] <= dims[-1] < state_dim:
            raise ValueError(f"held state dimensions {dims} out of range for {state_dim}-D states")
        key = (tuple(dims), pairs)  # the state size follows from pairs (checked above)
        if key not in self._held_parts:
            first_weight = self.weights[0]
            held_weight = first_weight[dims]
            if pairs:  # s and s' of a transition hold the same values
                held_weight = held_weight + first_weight[[state_dim + dim for dim in dims]]
            held_inputs = set(dims) | ({state_dim + dim for dim in dims} if pairs else set())
            read = [index for index in range(self.input_size) if index not in held_inputs]
            self._held_parts[key] = (ctypes.c_int * len(read))(*read), held_weight
        read_array, held_weight = self._held_parts[key]
        group_biases = initial_states[:, dims].to(held_weight) @ held_weight
        if len(self.weights) > 1:  # a single layer's bias is the output bias, the caller's
            group_biases += self.biases[0]
        return HeldInputs(read_array, group_biases.contiguous(), self.input_size)

    def marked_up_sums(
        self,
        states: th.Tensor,
        markups: th.Tensor,
        pairs: bool,
        out: th.Tensor,
        held: Optional[HeldInputs] = None,
        form: str = "logit",
    ) -> th.Tensor:
        """
        ``out[c] = sum_t markups[t] z(t, c)``, with ``z`` the MLP's output before its last bias on
        ``[states[t, c], states[t + 1, c]]`` (``pairs``) or on ``states[t, c]``; with a ``form`` other than
        ``"logit"``, that form of the output with its bias.

        :param states: ``(steps + 1, columns, state_dim)`` with ``pairs``, else ``(steps, columns, state_dim)``,
            CPU float32, any strides (read in place)
        :param markups: ``(steps,)``, CPU float32
        :param pairs: whether the MLP's input is a transition ``[s, s']``
        :param out: ``(columns,)``, contiguous CPU float32
        :param held: inputs constant within each env's columns (from :meth:`hold`), which are then not read; the
            columns are the envs' in turn, as many per env
        :param form: a key of :data:`FORM_CODES`
        :return: ``out``
        """
        read, n_read, group_biases, group_columns = None, self.input_size, None, 0
        if held is not None:
            groups = held.group_biases.shape[0]
            if held.input_size != self.input_size or held.group_biases.shape[1:] != (self.weights[0].shape[1],):
                raise ValueError("these held inputs were made for another MLP")
            if groups == 0 or states.shape[1] % groups != 0:
                raise ValueError(f"{states.shape[1]} columns do not split into the {groups} groups of the held inputs")
            read, n_read = ctypes.addressof(held.read), len(held.read)
            group_biases, group_columns = held.group_biases.data_ptr(), states.shape[1] // groups
        inputs, markups = _kernel_inputs(
            states, markups, pairs, out, self.input_size, n_read, read, group_biases, group_columns
        )  # fmt: skip
        self.library.mlp_costs(
            ctypes.byref(inputs), ctypes.byref(self._mlp), FORM_CODES[form], self.output_bias.data_ptr(), markups.data_ptr(),
            out.data_ptr(), th.get_num_threads(),
        )  # fmt: skip
        return out


def _check_input_size(input_size: int, state_dim: int, pairs: bool) -> None:
    if (2 if pairs else 1) * state_dim != input_size:
        raise ValueError(f"the MLP takes {input_size} inputs, not {'2 x ' if pairs else ''}{state_dim}")


def _kernel_inputs(
    states: th.Tensor,
    markups: th.Tensor,
    pairs: bool,
    out: th.Tensor,
    input_size: int,
    n_read: int,
    read: Optional[int] = None,
    group_biases: Optional[int] = None,
    group_columns: int = 0,
) -> Tuple[_Inputs, th.Tensor]:
    """
    The kernel's ``struct inputs`` for ``states`` and the contiguous ``markups`` it reads, after checking everything
    the kernel would otherwise read or write out of bounds (see :meth:`NativeMlp.marked_up_sums`).
    """
    n_states, columns, state_dim = states.shape
    steps = n_states - 1 if pairs else n_states
    _check_input_size(input_size, state_dim, pairs)
    if markups.shape != (steps,) or out.shape != (columns,) or not out.is_contiguous():
        raise ValueError(f"expected {steps} markups and a contiguous output of {columns} columns")
    if any(tensor.dtype != th.float32 or tensor.device.type != "cpu" for tensor in (states, markups, out)):
        raise ValueError("the CPU kernel takes CPU float32 tensors only")
    time_stride, column_stride, feature_stride = states.stride()
    inputs = _Inputs(
        states.data_ptr(), feature_stride, time_stride, column_stride, state_dim, int(pairs), steps, columns,
        n_read, read, group_biases, group_columns,
    )  # fmt: skip
    return inputs, markups.contiguous()


class NativeEnsemble:
    """
    An ensemble of frozen MLPs of one input size (one output each) evaluated by the compiled kernel: per input, the
    members' mean output less ``disagreement`` times their standard deviation (as
    :class:`~sb3_mpail.mppi.ensemble.DiscriminatorEnsemble` combines its logits). Build it with :meth:`from_members`.

    :param members: the members' kernel views
    :param output_biases: each member's output bias, ``(n_members,)``
    :param disagreement: weight of the members' standard deviation
    """

    def __init__(self, members: Sequence[NativeMlp], output_biases: th.Tensor, disagreement: float):
        self.members = list(members)  # kept alive: the kernel reads their weights through the structs below
        self.library = self.members[0].library
        self.input_size = self.members[0].input_size
        self.output_biases = output_biases.detach().to(th.float32).contiguous()
        self.disagreement = float(disagreement)
        self._mlps = (_Mlp * len(self.members))(*[member._mlp for member in self.members])

    @classmethod
    def from_members(
        cls, members: Sequence[Optional[NativeMlp]], output_biases: th.Tensor, disagreement: float
    ) -> Optional["NativeEnsemble"]:
        """
        :param members: each member's :meth:`NativeMlp.from_layers` view (``None`` where the kernel cannot take it)
        :param output_biases: each member's output bias, ``(n_members,)``
        :param disagreement: weight of the members' standard deviation
        :return: the kernel's view of the ensemble, or ``None`` where it cannot take one of the members, their input
            sizes differ, or there are fewer than 2 or more members than the kernel's limit
        """
        if any(member is None for member in members) or len({member.input_size for member in members}) != 1:
            return None
        if not 2 <= len(members) <= members[0].library.ensemble_max_members():
            return None
        return cls(members, output_biases, disagreement)

    def marked_up_sums(
        self, states: th.Tensor, markups: th.Tensor, pairs: bool, out: th.Tensor, form: str = "logit"
    ) -> th.Tensor:
        """
        ``out[c] = sum_t markups[t] e(t, c)``, with ``e`` the ``form`` of the ensemble's combined output (biases
        included) on ``[states[t, c], states[t + 1, c]]`` (``pairs``) or on ``states[t, c]``; arguments as
        :meth:`NativeMlp.marked_up_sums`'s, every input read.
        """
        inputs, markups = _kernel_inputs(states, markups, pairs, out, self.input_size, self.input_size)
        self.library.ensemble_costs(
            ctypes.byref(inputs), ctypes.addressof(self._mlps), len(self.members), self.output_biases.data_ptr(),
            self.disagreement, FORM_CODES[form], markups.data_ptr(), out.data_ptr(), th.get_num_threads(),
        )  # fmt: skip
        return out


#: bytes of torch's CPU generator state (``CPUGeneratorImplState``), whose head ``normal_noise.c`` reads and advances
_GENERATOR_STATE_BYTES = 5056
#: sizes the noise kernel is checked at before first use: one block, a tail of 7, and 2^20 + 3 across many twists
_CHECKED_SIZES = (16, 1007, 2**20 + 3)


def standard_normal(
    shape: Tuple[int, ...], generator: Optional[th.Generator], device: th.device, dtype: th.dtype
) -> th.Tensor:
    """
    ``torch.randn(shape, generator=generator, device=device, dtype=dtype)``: the same numbers, and the generator left in
    the same state, drawn by ``normal_noise.c`` for CPU float32 where it reproduces torch's (:func:`_normal_fill`).
    Unlike ``torch.randn`` it does not lock the generator: another thread drawing from it meanwhile may repeat its draws.
    """
    fill = _normal_fill() if th.device(device).type == "cpu" and dtype == th.float32 and math.prod(shape) >= 16 else None
    source = th.default_generator if generator is None else generator
    state = source.get_state() if fill is not None and source.device.type == "cpu" else None
    if state is None or state.numel() != _GENERATOR_STATE_BYTES:
        return th.randn(shape, generator=generator, device=device, dtype=dtype)
    out = th.empty(shape, dtype=th.float32, device="cpu")
    fill(state.data_ptr(), out.data_ptr(), out.numel(), th.get_num_threads())
    source.set_state(state)
    return out


@cache
def _normal_fill() -> Optional[Callable[[int, int, int, int], None]]:
    """
    The kernel's ``standard_normal_fill``, where it draws ``torch.randn``'s numbers: built for AVX2 and FMA, torch
    taking its AVX2 normal kernel (CPU capability AVX2 or AVX512: torch keeps the AVX2 one there too), torch's
    generator state of the layout the kernel reads, and the same numbers and final state as torch at
    ``_CHECKED_SIZES`` from a generator part-way through its words. Else ``None``, with a warning if the draws differ.
    """
    library = load_library()
    if library is None or not hasattr(library, "standard_normal_fill"):
        return None
    if th.backends.cpu.get_cpu_capability() not in ("AVX2", "AVX512"):
        return None
    generator = th.Generator().manual_seed(20261201)
    th.randn(5, generator=generator)  # below 16 numbers torch takes another path, which caches a spare normal
    if generator.get_state().numel() != _GENERATOR_STATE_BYTES:
        return None
    for size in _CHECKED_SIZES:
        state = generator.get_state()
        drawn = th.empty(size, dtype=th.float32, device="cpu")
        library.standard_normal_fill(state.data_ptr(), drawn.data_ptr(), size, th.get_num_threads())
        expected = th.randn(size, generator=generator, dtype=th.float32, device="cpu")
        if not (th.equal(drawn.view(th.int32), expected.view(th.int32)) and th.equal(state, generator.get_state())):
            warnings.warn("sb3_mpail: the noise kernel does not reproduce torch.randn here; using torch.randn", stacklevel=2)
            return None
    return library.standard_normal_fill
