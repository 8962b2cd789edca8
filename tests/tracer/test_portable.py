"""tracer/maths/portable.py: right, and the same bits whatever BLAS kernel or numpy SIMD dispatch
runs."""

import hashlib
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.cpu_variants import OPENBLAS_CORES, host_flags, numpy_avx512_targets
from tracer.maths import portable

ROOT = Path(__file__).resolve().parents[2]


def random_affine(rng: np.random.Generator) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rng.normal(size=(3, 3))
    m[:3, 3] = rng.normal(size=3) * 10.0
    return m


def test_agrees_with_numpy_to_rounding():
    rng = np.random.default_rng(7)
    for _ in range(200):
        a, b = rng.normal(size=3), rng.normal(size=3)
        m, n = random_affine(rng), random_affine(rng)
        points = rng.normal(size=(5, 3))
        assert portable.dot(a, b) == pytest.approx(float(a @ b), rel=1e-12, abs=1e-14)
        assert portable.norm(a) == pytest.approx(float(np.linalg.norm(a)), rel=1e-15)
        np.testing.assert_allclose(portable.cross(a, b), np.cross(a, b), rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(portable.matmul(m, n), m @ n, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(portable.chain(m, n, m), m @ n @ m, rtol=1e-11, atol=1e-11)
        expected = points @ m[:3, :3].T + m[:3, 3]
        np.testing.assert_allclose(
            portable.transform_points(points, m), expected, rtol=1e-12, atol=1e-12
        )
        np.testing.assert_allclose(portable.affine_inverse(m) @ m, np.eye(4), atol=1e-9)
        assert portable.det3(m) == pytest.approx(float(np.linalg.det(m[:3, :3])), rel=1e-10)
    stack = np.stack([random_affine(rng) for _ in range(4)])
    np.testing.assert_allclose(portable.det3(stack), np.linalg.det(stack[:, :3, :3]), rtol=1e-10)


def test_edge_cases():
    assert portable.norm([3e200, 4e200, 0.0]) == pytest.approx(5e200, rel=1e-15)  # no overflow
    assert portable.norm([0.0, 0.0, 0.0]) == 0.0
    np.testing.assert_array_equal(portable.affine_inverse(np.diag([2.0, 4.0, 0.5, 1.0])),
                                  np.diag([0.5, 0.25, 2.0, 1.0]))  # fmt: skip
    with pytest.raises(ZeroDivisionError):
        portable.affine_inverse(np.diag([1.0, 0.0, 1.0, 1.0]))
    mirrored = np.diag([-1.0, 1.0, 1.0, 1.0])
    assert portable.det3(mirrored) == -1.0
    np.testing.assert_array_equal(portable.elementwise(math.sqrt, [[4.0, 9.0]]), [[2.0, 3.0]])


def test_small_matrices_in_python_floats_give_the_vector_codes_bits():
    """matmul and det3 of one small matrix take the Python-float path; a stack of one (the
    vector code) must give the same bits, for ordinary, huge (overflowing) and odd-shaped
    values."""
    rng = np.random.default_rng(11)
    cases = [(random_affine(rng), random_affine(rng)) for _ in range(200)]
    cases += [(rng.normal(size=(3, 3)) * 1e300, rng.normal(size=(3, 3)) * 1e10) for _ in range(20)]
    cases += [(rng.normal(size=(2, 4)), rng.normal(size=(4, 3))) for _ in range(20)]
    cases.append((np.full((3, 3), np.inf), np.zeros((3, 3))))
    with np.errstate(all="ignore"):
        for a, b in cases:
            small = portable.matmul(a, b)
            stacked = portable.matmul(a[None], b[None])[0]
            assert small.dtype == np.float64 and small.shape == stacked.shape
            assert small.tobytes() == stacked.tobytes()
            if a.shape[0] >= 3 and a.shape[1] >= 3:
                det = portable.det3(a)
                assert isinstance(det, float)
                assert np.float64(det).tobytes() == portable.det3(a[None])[0].tobytes()


PROBE = """
import hashlib, math, numpy as np
from tracer.maths import portable
rng = np.random.default_rng(3)
h = hashlib.sha256()
for _ in range(300):
    m = np.eye(4); m[:3, :3] = rng.normal(size=(3, 3)); m[:3, 3] = rng.normal(size=3)
    v = rng.normal(size=3); p = rng.normal(size=(7, 3))
    for x in (portable.norm(v), portable.dot(v, v), portable.normalized(v),
              portable.cross(v, p[0]), portable.chain(m, m, m), portable.transform_points(p, m),
              portable.affine_inverse(m), portable.det3(m), portable.elementwise(math.tan, p),
              portable.elementwise(math.exp, v)):
        h.update(np.asarray(x, np.float64).tobytes())
print(h.hexdigest())
"""


def probe(env: dict[str, str]) -> str:
    result = subprocess.run(
        [sys.executable, "-c", PROBE], env={**os.environ, **env}, cwd=ROOT,
        capture_output=True, text=True, check=True, timeout=120,
    )  # fmt: skip
    return result.stdout.strip()


def test_same_bits_with_every_blas_kernel_and_numpy_dispatch():
    flags = host_flags()
    variants = [{"OPENBLAS_CORETYPE": c} for c, needs in OPENBLAS_CORES.items() if needs <= flags]
    if numpy_avx512_targets():
        variants.append({"NPY_DISABLE_CPU_FEATURES": " ".join(numpy_avx512_targets())})
    digests = {str(v): probe(v) for v in variants}
    assert len(set(digests.values())) == 1, digests
    assert hashlib.sha256(b"").hexdigest() not in digests.values()
