"""Chi-square goodness-of-fit test of a direction sampler against its density (after Mitsuba's
``chi2.py``).

Directions are binned on the sphere in (cos(theta), phi), where equal-sized cells have equal
solid angle. The expected count of a cell is the sample count times the integral of the
claimed density over the cell (midpoint rule on a finer grid). Cells with small expected counts
are pooled into one (as Mitsuba does), so the chi-square approximation holds; the test rejects
when the p-value falls below a level the caller Sidak-corrects for the number of tests.
A sampler that loses samples (failures, pdf 0) is consistent when its density integrates to
the fraction of successful samples, which the histogram sees as missing mass.
"""

from dataclasses import dataclass

import numpy as np
from scipy import stats

from tests.stats import sidak

MIN_EXPECTED = 5.0
"""Cells expecting fewer samples are pooled."""


@dataclass
class Chi2Result:
    statistic: float
    dof: int
    p_value: float
    observed: np.ndarray
    expected: np.ndarray
    pdf_integral: float
    """Integral of the density over the sphere (at most 1; less where samples fail)."""

    def table(self) -> str:
        """Observed and expected counts of the worst cells, for failure messages."""
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (self.observed - self.expected) / np.sqrt(np.maximum(self.expected, 1e-300))
        worst = np.argsort(-np.abs(z).ravel())[:8]
        rows = [
            f"cell {np.unravel_index(i, self.observed.shape)}: observed "
            f"{self.observed.ravel()[i]:.0f} expected {self.expected.ravel()[i]:.1f}"
            for i in worst
        ]
        return "\n".join(rows)


def direction_cells(directions: np.ndarray, res_theta: int, res_phi: int) -> np.ndarray:
    """Histogram of unit vectors (N, 3) over ``res_theta`` x ``res_phi`` (cos theta, phi) cells."""
    cos_t = np.clip(directions[:, 2], -1.0, 1.0)
    phi = np.arctan2(directions[:, 1], directions[:, 0]) % (2.0 * np.pi)
    i = np.minimum(((1.0 - cos_t) * 0.5 * res_theta).astype(np.int64), res_theta - 1)
    j = np.minimum((phi / (2.0 * np.pi) * res_phi).astype(np.int64), res_phi - 1)
    counts = np.zeros((res_theta, res_phi))
    np.add.at(counts, (i, j), 1.0)
    return counts


def integrate_pdf(pdf, res_theta: int, res_phi: int, sub: int = 32) -> np.ndarray:
    """Integral of ``pdf`` (a function of unit vectors (M, 3) -> densities (M,)) over each cell,
    by the midpoint rule on ``sub`` x ``sub`` points per cell."""
    n_t = res_theta * sub
    n_p = res_phi * sub
    cos_t = 1.0 - 2.0 * (np.arange(n_t) + 0.5) / n_t
    phi = 2.0 * np.pi * (np.arange(n_p) + 0.5) / n_p
    ct, ph = np.meshgrid(cos_t, phi, indexing="ij")
    st = np.sqrt(np.maximum(0.0, 1.0 - ct * ct))
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], axis=-1).reshape(-1, 3)
    values = np.asarray(pdf(dirs), dtype=np.float64).reshape(n_t, n_p)
    cell = (2.0 / n_t) * (2.0 * np.pi / n_p)
    return values.reshape(res_theta, sub, res_phi, sub).sum(axis=(1, 3)) * cell


def chi2_test(
    directions: np.ndarray, pdf, samples: int, res_theta: int = 32, res_phi: int = 64
) -> Chi2Result:
    """Compare the histogram of ``directions`` (the successful ones of ``samples`` draws) with
    ``samples`` times the cell integrals of ``pdf``."""
    observed = direction_cells(directions, res_theta, res_phi)
    integrals = integrate_pdf(pdf, res_theta, res_phi)
    expected = integrals * samples
    small = expected < MIN_EXPECTED
    obs = list(observed[~small])
    exp = list(expected[~small])
    pooled_obs = observed[small].sum()
    pooled_exp = expected[small].sum()
    if pooled_exp > 0.0 or pooled_obs > 0.0:
        obs.append(pooled_obs)
        exp.append(pooled_exp)
    obs = np.array(obs)
    exp = np.array(exp)
    if np.any((exp == 0.0) & (obs > 0.0)):
        return Chi2Result(np.inf, len(obs) - 1, 0.0, observed, expected, float(integrals.sum()))
    keep = exp > 0.0
    statistic = float(np.sum((obs[keep] - exp[keep]) ** 2 / exp[keep]))
    dof = int(keep.sum()) - 1
    p = float(stats.chi2.sf(statistic, dof))
    return Chi2Result(statistic, dof, p, observed, expected, float(integrals.sum()))


def level(alpha: float, tests: int) -> float:
    """Per-test significance level for ``tests`` tests at family-wise level ``alpha``."""
    return sidak(alpha, tests)
