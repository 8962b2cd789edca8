"""Counter-based random numbers: every draw is a pure function of its inputs.

A pixel's key is a hash of (seed, frame, pixel); a sample's key is SplitMix64's output number
``sample`` from the pixel key; draw ``dim`` of a sample is output number ``dim`` from the
sample key. ``uniform2`` takes two 32-bit uniforms from one output. No state is carried
between pixels, threads or line ranges, which is what makes any split of a frame bit-identical
(DESIGN.md, invariant 1).
"""

import numpy as np

from tracer.kernel.jit import jit

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MUL1 = np.uint64(0xBF58476D1CE4E5B9)
_MUL2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_S32 = np.uint64(32)
_LOW32 = np.uint64(0xFFFFFFFF)
_INV_2_53 = 1.0 / 9007199254740992.0
_INV_2_32 = 1.0 / 4294967296.0


@jit
def mix64(z):
    """SplitMix64's finaliser: a bijective avalanche of a uint64."""
    z = np.uint64(z)
    z = (z ^ (z >> _S30)) * _MUL1
    z = (z ^ (z >> _S27)) * _MUL2
    return z ^ (z >> _S31)


@jit
def pixel_key(seed, frame, pixel):
    """Key of one pixel of one frame; all arguments are non-negative integers."""
    h = mix64(np.uint64(seed) + _GOLDEN)
    h = mix64(h ^ np.uint64(frame))
    return mix64((h + _GOLDEN) ^ np.uint64(pixel))


@jit
def sample_key(pixel, sample):
    """Key of sample number ``sample`` of the pixel with key ``pixel``."""
    return mix64(np.uint64(pixel) + np.uint64(sample + 1) * _GOLDEN)


@jit
def uniform(key, dim):
    """Uniform float64 in [0, 1), 53 random bits, for dimension ``dim`` of the sample ``key``."""
    bits = mix64(np.uint64(key) + np.uint64(dim + 1) * _GOLDEN)
    return np.float64(bits >> _S11) * _INV_2_53


@jit
def uniform2(key, dim):
    """Two uniforms in [0, 1), 32 random bits each, from one draw (dimension ``dim``)."""
    bits = mix64(np.uint64(key) + np.uint64(dim + 1) * _GOLDEN)
    return np.float64(bits >> _S32) * _INV_2_32, np.float64(bits & _LOW32) * _INV_2_32
