"""Other CPUs emulated on this one: the knobs that change which machine code numba, numpy and
its OpenBLAS run, limited to what this host can execute (x86-64 Linux).

- numba: ``NUMBA_CPU_NAME`` with ``NUMBA_CPU_FEATURES=""`` (that CPU's own features; without
  it numba keeps the host's, AVX-512 included), in a kernel cache of its own;
- OpenBLAS: ``OPENBLAS_CORETYPE`` (numpy's bundled build runs Zen as Haswell, Prescott as
  Katmai);
- numpy: ``NPY_DISABLE_CPU_FEATURES`` naming dispatch targets (``X86_V4``, ``AVX512_*``).

glibc's libm is left alone: on CPUs without FMA and AVX2 it runs other, not bit-identical code
(``GLIBC_TUNABLES=glibc.cpu.hwcaps=-FMA,-AVX2``), outside what the project promises
(``docs/cluster.md``).
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass, field
from pathlib import Path


def host_flags() -> frozenset[str]:
    """The CPU flags of /proc/cpuinfo."""
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("flags"):
            return frozenset(line.split(":", 1)[1].split())
    return frozenset()


def numpy_dispatch() -> list[str]:
    """numpy's SIMD dispatch targets this process uses (built in and not disabled)."""
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    return [name for name in __cpu_dispatch__ if __cpu_features__.get(name)]


def openblas_corename() -> str:
    """The kernel set numpy's OpenBLAS picked in this process ('' if it cannot be asked)."""
    import numpy  # noqa: F401 - loads OpenBLAS

    for line in Path("/proc/self/maps").read_text().splitlines():
        if "openblas" in line.lower():
            lib = ctypes.CDLL(line.split()[-1])
            for symbol in ("scipy_openblas_get_corename64_", "openblas_get_corename"):
                function = getattr(lib, symbol, None)
                if function is not None:
                    function.restype = ctypes.c_char_p
                    return function().decode().strip()
    return ""


@dataclass(frozen=True)
class Variant:
    """An emulated CPU: a name and the environment variables that make this host run it."""

    name: str
    env: dict[str, str] = field(default_factory=dict)
    numba: str | None = None
    """numba's target CPU (``NUMBA_CPU_NAME``); None for the host's."""
    host_features: bool = False
    """numba keeps the host's CPU features (no ``NUMBA_CPU_FEATURES``) with ``numba``."""

    @property
    def cache_key(self) -> str | None:
        """The kernel cache this variant's code belongs in (None: the parent's)."""
        if self.numba is None:
            return None
        return f"{self.numba}+host-features" if self.host_features else self.numba


def numpy_avx512_targets() -> list[str]:
    """numpy dispatch targets in use that need AVX-512 (what a CPU without it cannot run)."""
    return [t for t in numpy_dispatch() if t.startswith("AVX512") or t == "X86_V4"]


def numba_env(cpu: str) -> dict[str, str]:
    """numba generating code for ``cpu`` with that CPU's own features (an empty feature string
    makes LLVM take the CPU's; without it numba keeps the host's features, AVX-512 included)."""
    return {"NUMBA_CPU_NAME": cpu, "NUMBA_CPU_FEATURES": ""}


def epyc() -> Variant | None:
    """An AMD EPYC (Zen 2: AVX2 and FMA, no AVX-512) as far as this host can pretend."""
    if not {"avx2", "fma", "bmi2"} <= host_flags():
        return None
    env = {**numba_env("znver2"), "OPENBLAS_CORETYPE": "Zen"}
    if numpy_avx512_targets():
        env["NPY_DISABLE_CPU_FEATURES"] = " ".join(numpy_avx512_targets())
    return Variant("epyc", env, numba="znver2")


def baseline() -> Variant:
    """An old x86-64 baseline: generic code, OpenBLAS's oldest kernels, numpy's baseline SIMD
    only."""
    env = {"NUMBA_CPU_NAME": "generic", "OPENBLAS_CORETYPE": "Prescott"}
    if numpy_dispatch():
        env["NPY_DISABLE_CPU_FEATURES"] = " ".join(numpy_dispatch())
    return Variant("baseline", env, numba="generic")


NUMBA_TARGETS = {
    "generic": frozenset(),
    "haswell": frozenset({"avx2", "fma", "bmi1", "bmi2", "movbe", "f16c", "abm"}),
    "znver2": frozenset({"avx2", "fma", "bmi1", "bmi2", "movbe", "f16c", "adx", "sha_ni"}),
    "skylake-avx512": frozenset({"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"}),
}
"""numba targets of the wide matrix and the host flags each needs to run here."""
OPENBLAS_CORES = {
    "Prescott": frozenset({"pni"}),  # SSE3
    "Nehalem": frozenset({"sse4_2"}),
    "Sandybridge": frozenset({"avx"}),
    "Haswell": frozenset({"avx2", "fma"}),
    "Zen": frozenset({"avx2", "fma"}),
    "SkylakeX": frozenset({"avx512f", "avx512bw", "avx512dq", "avx512vl"}),
}
"""OpenBLAS core types of the wide matrix and the host flags each needs."""


def matrix() -> list[Variant]:
    """The wide matrix: each numba target (own cache), each OpenBLAS core type, numpy's
    dispatch without AVX-512 and without any, each knob alone, then the two emulated machines
    with every knob together."""
    flags = host_flags()
    variants = [
        Variant(f"numba-{cpu}", numba_env(cpu), numba=cpu)
        for cpu, needs in NUMBA_TARGETS.items()
        if needs <= flags
    ]
    variants.append(Variant("numba-host", {"NUMBA_CPU_NAME": "host"}, "host", True))
    if NUMBA_TARGETS["znver2"] <= flags:  # Zen 2 scheduling, the host's AVX-512: zmm code
        znver2 = {"NUMBA_CPU_NAME": "znver2"}
        variants.append(Variant("numba-znver2-host-features", znver2, "znver2", True))
    variants += [
        Variant(f"openblas-{core}", {"OPENBLAS_CORETYPE": core})
        for core, needs in OPENBLAS_CORES.items()
        if needs <= flags
    ]
    if numpy_avx512_targets():
        disabled = " ".join(numpy_avx512_targets())
        variants.append(Variant("numpy-no-avx512", {"NPY_DISABLE_CPU_FEATURES": disabled}))
    if numpy_dispatch():
        disabled = " ".join(numpy_dispatch())
        variants.append(Variant("numpy-baseline", {"NPY_DISABLE_CPU_FEATURES": disabled}))
    variants += [v for v in (epyc(), baseline()) if v is not None]
    return variants


def other_cpu() -> Variant:
    """The emulated CPU least like this host: an EPYC where the host has AVX-512 (its numba
    target, OpenBLAS kernels and numpy dispatch all differ), else the old baseline."""
    variant = epyc() if "avx512f" in host_flags() else None
    return variant or baseline()
