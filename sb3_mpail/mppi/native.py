"""
The planner's CPU kernel: a small MLP's cost over many rows in one pass (``mlp_cost.c`` beside this module).

The torch path of :mod:`sb3_mpail.mppi.fused` runs each layer as a matrix product over a chunk of rows and then adds
the bias and activation in passes of their own, so every layer's output goes to memory and back. The kernel instead
runs every layer for a block of rows while it is in the L1 cache and sums the marked-up outputs over the horizon
(``BENCHMARKS.md``, "planner_speed", times the planner with and without it).

It is compiled at first use with the machine's C compiler (``$CC``, else ``cc``, ``gcc`` or ``clang``) for the
machine's own instruction set and linked to the GNU OpenMP runtime torch has loaded, so its threads are torch's
(as many as ``torch.get_num_threads()``). The library is cached under ``$SB3_MPAIL_CACHE`` (default
``~/.cache/sb3_mpail``), one file per source, compiler, OpenMP runtime and CPU. Without a compiler or that runtime
(torch builds for macOS use another), or with ``SB3_MPAIL_NATIVE=0``, the planner keeps the torch path (a warning
says why, once); the two agree to float rounding.
"""

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import warnings
from functools import cache
from pathlib import Path
from typing import List, Optional

import torch as th

SOURCE = Path(__file__).with_name("mlp_cost.c")
COMPILER_FLAGS = ("-O3", "-march=native", "-fno-strict-aliasing", "-fPIC", "-fopenmp")
#: activation codes of ``mlp_cost.c``, by the fused paths' oneDNN names
ACTIVATION_CODES = {"relu": 1, "leaky_relu": 2, "tanh": 3}


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
    """Compiles the kernel unless the cache has it; the library appears whole or not at all (an atomic rename)."""
    openmp = _openmp_runtime()
    text = [compiler, *COMPILER_FLAGS, str(openmp), _cpu_description()]
    key = hashlib.sha256(b"\0".join([SOURCE.read_bytes(), *(part.encode() for part in text)]))
    directory = _cache_directory()
    library = directory / f"mlp_cost-{key.hexdigest()[:16]}.so"
    if library.exists():
        return library
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=directory) as build_directory:
        built, objects = Path(build_directory) / library.name, Path(build_directory) / "mlp_cost.o"
        # linked to torch's OpenMP file itself (not -fopenmp's -lgomp, which may name another copy of the runtime)
        for command in (
            [compiler, *COMPILER_FLAGS, "-c", str(SOURCE), "-o", str(objects)],
            [compiler, "-shared", str(objects), str(openmp), "-lm", "-o", str(built)],
        ):
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
    pointer = ctypes.c_void_p
    library.mlp_max_width.restype = ctypes.c_int
    library.mlp_costs.restype = None
    integer, long = ctypes.c_int, ctypes.c_long
    library.mlp_costs.argtypes = [pointer, long, long, long, integer, integer, integer, long, integer] + [pointer] * 7
    library.mlp_costs.argtypes += [integer]
    return library


class NativeMlp:
    """
    A frozen MLP (one output, no activation after it) evaluated by the compiled kernel, on CPU float32 tensors.
    Build it with :meth:`from_layers`, which returns ``None`` where the kernel cannot take the network.

    :param library: the loaded kernel
    :param weights: per layer, the weight ``(out, in)``, contiguous float32
    :param biases: per layer but the last, the bias ``(out,)``
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
        self.weights, self.biases = weights, biases  # kept alive: the kernel reads them through the pointers below
        n_layers = len(weights)
        self.n_layers = n_layers
        self.input_size = weights[0].shape[1]
        self._widths = (ctypes.c_int * (n_layers + 1))(self.input_size, *[weight.shape[0] for weight in weights])
        self._weights = (ctypes.c_void_p * n_layers)(*[weight.data_ptr() for weight in weights])
        self._biases = (ctypes.c_void_p * n_layers)(*[bias.data_ptr() for bias in biases], None)
        self._activations = (ctypes.c_int * n_layers)(*activation_codes)
        self._slopes = (ctypes.c_float * n_layers)(*slopes)

    @classmethod
    def from_layers(
        cls, weights: List[th.Tensor], biases: List[th.Tensor], activations: List[Optional[str]], slopes: List[float]
    ) -> Optional["NativeMlp"]:
        """
        :param weights: per layer, the weight ``(in, out)`` as the fused paths hold it
        :param biases: per layer, the bias ``(out,)``; the last layer's is left to the caller
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
            [weight.t().contiguous() for weight in weights],
            [bias.contiguous() for bias in biases[:-1]],
            codes,
            [float(slope) for slope in slopes],
        )

    def marked_up_sums(self, states: th.Tensor, markups: th.Tensor, pairs: bool, out: th.Tensor) -> th.Tensor:
        """
        ``out[c] = sum_t markups[t] z(t, c)``, with ``z`` the MLP's output before its last bias on
        ``[states[t, c], states[t + 1, c]]`` (``pairs``) or on ``states[t, c]``.

        :param states: ``(steps + 1, columns, state_dim)`` with ``pairs``, else ``(steps, columns, state_dim)``,
            CPU float32, any strides (read in place)
        :param markups: ``(steps,)``, CPU float32
        :param pairs: whether the MLP's input is a transition ``[s, s']``
        :param out: ``(columns,)``, contiguous CPU float32
        :return: ``out``
        """
        n_states, columns, state_dim = states.shape
        steps = n_states - 1 if pairs else n_states
        # the kernel reads and writes raw memory: anything else than these shapes and types would go out of bounds
        if (2 if pairs else 1) * state_dim != self.input_size:
            raise ValueError(f"the MLP takes {self.input_size} inputs, not {'2 x ' if pairs else ''}{state_dim}")
        if markups.shape != (steps,) or out.shape != (columns,) or not out.is_contiguous():
            raise ValueError(f"expected {steps} markups and a contiguous output of {columns} columns")
        if any(tensor.dtype != th.float32 or tensor.device.type != "cpu" for tensor in (states, markups, out)):
            raise ValueError("the CPU kernel takes CPU float32 tensors only")
        markups = markups.contiguous()
        time_stride, column_stride, feature_stride = states.stride()
        self.library.mlp_costs(
            states.data_ptr(), feature_stride, time_stride, column_stride, state_dim, int(pairs), steps, columns,
            self.n_layers, self._widths, self._weights, self._biases, self._activations, self._slopes,
            markups.data_ptr(), out.data_ptr(), th.get_num_threads(),
        )  # fmt: skip
        return out
