"""Counter-based random numbers: every draw is a pure function of its inputs.

A sample's key is a hash of (seed, frame, pixel, sample index); draw ``dim`` of that sample is
SplitMix64's ``dim``-th output from the key. No state is carried between pixels, threads or line
ranges, which is what makes any split of a frame bit-identical (DESIGN.md, invariant 1).
"""

import numpy as np

from tracer.jit import jit

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MUL1 = np.uint64(0xBF58476D1CE4E5B9)
_MUL2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_INV_2_53 = 1.0 / 9007199254740992.0


@jit
def mix64(z):
    """SplitMix64's finaliser: a bijective avalanche of a uint64."""
    z = np.uint64(z)
    z = (z ^ (z >> _S30)) * _MUL1
    z = (z ^ (z >> _S27)) * _MUL2
    return z ^ (z >> _S31)


@jit
def sample_key(seed, frame, pixel, sample):
    """Key of one pixel sample; all arguments are non-negative integers."""
    h = mix64(np.uint64(seed) + _GOLDEN)
    h = mix64(h ^ np.uint64(frame))
    h = mix64((h + _GOLDEN) ^ np.uint64(pixel))
    return mix64((h + _GOLDEN) ^ np.uint64(sample))


@jit
def uniform(key, dim):
    """Uniform float64 in [0, 1) for dimension ``dim`` of the sample with ``key``."""
    bits = mix64(np.uint64(key) + np.uint64(dim + 1) * _GOLDEN)
    return np.float64(bits >> _S11) * _INV_2_53
