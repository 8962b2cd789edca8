"""Other CPUs emulated on this one: the knobs that change which machine code numpy, its BLAS and
numba run, limited to what the host can execute."""

from pathlib import Path


def host_flags() -> set[str]:
    """The CPU flags of /proc/cpuinfo (empty where there is none)."""
    cpuinfo = Path("/proc/cpuinfo")
    if not cpuinfo.exists():
        return set()
    for line in cpuinfo.read_text().splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


def blas_core_types() -> list[str]:
    """OpenBLAS kernels (``OPENBLAS_CORETYPE``) the host can run: a pre-AVX baseline always,
    the AVX2 ones with AVX2 and FMA, SkylakeX with AVX-512."""
    flags = host_flags()
    cores = ["Prescott"]
    if {"avx2", "fma"} <= flags:
        cores += ["Haswell", "Zen"]
    if "avx512f" in flags:
        cores.append("SkylakeX")
    return cores


def numpy_without_avx512() -> dict[str, str]:
    """Environment that keeps numpy off its AVX-512 code (as on an AMD EPYC without it); empty
    where numpy would not run such code anyway."""
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    targets = [t for t in __cpu_dispatch__ if t in ("X86_V4",) or t.startswith("AVX512")]
    enabled = [t for t in targets if __cpu_features__.get(t, False)]
    return {"NPY_DISABLE_CPU_FEATURES": " ".join(enabled)} if enabled else {}
