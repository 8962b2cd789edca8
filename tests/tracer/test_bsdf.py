"""BSDFs (``tracer.shading.bsdf``, ``tracer.shading.microfacet``, ``tracer.shading.fresnel``):
sampling agrees with the claimed densities (chi-square), sample weights agree with evaluation,
reciprocity, Fresnel values, and the delta lobes' directions and probabilities."""

import itertools
import math

import numpy as np
import pytest
from numba import njit

from tests.chi2 import chi2_test, level
from tracer.scene import format as fmt
from tracer.shading import bsdf, materials
from tracer.shading.fresnel import fr_conductor, fr_dielectric
from tracer.shading.materials import (
    coat_tables,
    conductor_index_from_reflectance,
    gauss_legendre,
    material_row,
)
from tracer.shading.microfacet import (
    ggx_dielectric_albedo,
    ggx_sample_visible_normal,
    ggx_visible_normal_pdf,
)

N = (0.0, 0.0, 1.0)
SAMPLES = 400_000
CASES = 14
"""Chi-square tests in this module (the Sidak correction of each test's level)."""
ALPHA = level(0.01, CASES)


def direction(theta_deg: float) -> tuple[float, float, float]:
    t = math.radians(theta_deg)
    return (math.sin(t) * 0.8, math.sin(t) * 0.6, math.cos(t))


def row(material):
    """``(kind, albedo, param)``: ``param`` the material's parameter row split as the kernels
    pass it, ``(scalar tuple, whole row)``."""
    kind, albedo, _, _, param = material_row(material)
    scalars = tuple(float(p) for p in param[: bsdf.PARAMS])
    return kind, tuple(float(a) for a in albedo), (scalars, param)


def _sample_many(kind, albedo, param, wo, front, count, seed):
    u = np.random.default_rng(seed).random((count, 3))
    return _sample_with(kind, albedo, param, wo, front, u)


@njit(cache=True)
def _sample_with(kind, albedo, param, wo, front, u):
    count = u.shape[0]
    dirs = np.empty((count, 3))
    weights = np.empty((count, 3))
    pdfs = np.empty(count)
    deltas = np.empty(count, np.bool_)
    for i in range(count):
        wi, weight, pdf, delta = bsdf.bsdf_sample(
            kind, albedo, param[0], param[1], N, wo, front, True, u[i, 0], u[i, 1], u[i, 2]
        )
        dirs[i, 0] = wi[0]
        dirs[i, 1] = wi[1]
        dirs[i, 2] = wi[2]
        weights[i, 0] = weight[0]
        weights[i, 1] = weight[1]
        weights[i, 2] = weight[2]
        pdfs[i] = pdf
        deltas[i] = delta
    return dirs, weights, pdfs, deltas


@njit(cache=True)
def _eval_many(kind, albedo, param, wo, dirs):
    f = np.empty((dirs.shape[0], 3))
    pdf = np.empty(dirs.shape[0])
    for i in range(dirs.shape[0]):
        wi = (dirs[i, 0], dirs[i, 1], dirs[i, 2])
        fi, p = bsdf.bsdf_eval(kind, albedo, param[0], param[1], N, wo, wi)
        f[i, 0] = fi[0]
        f[i, 1] = fi[1]
        f[i, 2] = fi[2]
        pdf[i] = p
    return f, pdf


def _visible_normals(wo, alpha, count, seed):
    return _visible_normals_with(wo, alpha, np.random.default_rng(seed).random((count, 2)))


@njit(cache=True)
def _visible_normals_with(wo, alpha, u):
    count = u.shape[0]
    out = np.empty((count, 3))
    for i in range(count):
        m = ggx_sample_visible_normal(wo, alpha, u[i, 0], u[i, 1])
        out[i, 0] = m[0]
        out[i, 1] = m[1]
        out[i, 2] = m[2]
    return out


@njit(cache=True)
def _visible_normal_pdf(wo, alpha, dirs):
    out = np.empty(dirs.shape[0])
    for i in range(dirs.shape[0]):
        out[i] = ggx_visible_normal_pdf(wo, (dirs[i, 0], dirs[i, 1], dirs[i, 2]), alpha)
    return out


def check_sampler(material, wo, seed=1):
    """Chi-square of a material's samples against its pdf; then, for every sample, the weight
    is f * cos / pdf of the evaluation at the sampled direction."""
    kind, albedo, param = row(material)
    dirs, weights, pdfs, deltas = _sample_many(kind, albedo, param, wo, True, SAMPLES, seed)
    ok = pdfs > 0.0
    assert not deltas.any()
    result = chi2_test(dirs[ok], lambda d: _eval_many(kind, albedo, param, wo, d)[1], SAMPLES)
    assert result.p_value > ALPHA, f"p = {result.p_value:.3g}\n{result.table()}"
    # The density integrates to the fraction of samples that succeed.
    assert abs(result.pdf_integral - ok.mean()) < 0.01
    f, pdf = _eval_many(kind, albedo, param, wo, dirs[ok][:2000])
    np.testing.assert_allclose(pdf, pdfs[ok][:2000], rtol=1e-9)
    np.testing.assert_allclose(f / pdf[:, None], weights[ok][:2000], rtol=1e-9)
    return weights[ok].sum(axis=0) / SAMPLES


def test_lambertian_sampling_matches_its_pdf():
    """Cosine-weighted sampling: chi-square, and every weight is the albedo."""
    check_sampler(fmt.DiffuseMaterial(reflectance=(0.5, 0.6, 0.7)), direction(30.0))


@pytest.mark.parametrize("roughness, theta", [(0.3, 0.0), (0.3, 60.0), (0.7, 30.0), (0.7, 80.0)])
def test_rough_conductor_sampling_matches_its_pdf(roughness, theta):
    """Visible-normal sampling of the GGX conductor (reflected directions) against
    ``G1(wo) D(h) / (4 cos_o)``, at normal, oblique and grazing views."""
    check_sampler(fmt.ConductorMaterial(type="conductor", roughness=roughness), direction(theta))


@pytest.mark.parametrize(
    "roughness, reflectance, theta",
    [
        (0.2, (0.5, 0.5, 0.5), 20.0),
        (0.5, (0.9, 0.1, 0.1), 70.0),
        (0.8, (0.05, 0.05, 0.05), 40.0),
        (1.0, (0.5, 0.5, 0.5), 85.0),
    ],
)
def test_plastic_sampling_matches_its_pdf(roughness, reflectance, theta):
    """The plastic's two-lobe mixture (specular choice weighted by the rough coat's tabulated
    reflectance) against its pdf; the last case, grazing at roughness 1, is where the table
    departs most from the smooth interface's Fresnel term."""
    material = fmt.PlasticMaterial(type="plastic", roughness=roughness, reflectance=reflectance)
    check_sampler(material, direction(theta))


@pytest.mark.parametrize("alpha, theta", [(0.1, 0.0), (0.3, 45.0), (0.6, 85.0)])
def test_visible_normal_sampling_matches_its_pdf(alpha, theta):
    """Heitz's visible-normal sampling against D_wo(m) = G1(wo) max(0, wo.m) D(m) / wo.z."""
    wo = direction(theta)
    normals = _visible_normals(wo, alpha, SAMPLES, 3)
    result = chi2_test(normals, lambda d: _visible_normal_pdf(wo, alpha, d), SAMPLES)
    assert result.p_value > ALPHA, f"p = {result.p_value:.3g}\n{result.table()}"
    # The midpoint rule under-integrates the sharp lobe of alpha 0.1 by about 1%.
    assert abs(result.pdf_integral - 1.0) < 0.02


def test_the_chi2_test_can_fail():
    """Negative control: samples of one roughness against another's pdf are rejected."""
    kind, albedo, param = row(fmt.ConductorMaterial(type="conductor", roughness=0.5))
    _, _, other = row(fmt.ConductorMaterial(type="conductor", roughness=0.45))
    wo = direction(30.0)
    dirs, _, pdfs, _ = _sample_many(kind, albedo, param, wo, True, SAMPLES, 5)
    result = chi2_test(dirs[pdfs > 0], lambda d: _eval_many(kind, albedo, other, wo, d)[1], SAMPLES)
    assert result.p_value < 1e-6


@pytest.mark.parametrize(
    "material",
    [
        fmt.ConductorMaterial(type="conductor", roughness=0.4, reflectance=(0.9, 0.6, 0.3)),
        fmt.PlasticMaterial(type="plastic", roughness=0.3, reflectance=(0.4, 0.5, 0.6)),
    ],
)
def test_reciprocity(material):
    """f(wo, wi) = f(wi, wo): f * cos_i / cos_i is symmetric for the microfacet models."""
    kind, albedo, param = row(material)
    rng = np.random.default_rng(0)
    for _ in range(50):
        a, b = rng.normal(size=(2, 3))
        a[2], b[2] = abs(a[2]), abs(b[2])
        wo = tuple(a / np.linalg.norm(a))
        wi = tuple(b / np.linalg.norm(b))
        f1, _ = bsdf.bsdf_eval(kind, albedo, *param, N, wo, wi)
        f2, _ = bsdf.bsdf_eval(kind, albedo, *param, N, wi, wo)
        np.testing.assert_allclose(np.array(f1) / wi[2], np.array(f2) / wo[2], rtol=1e-9)


def test_microfacet_albedo_is_at_most_one():
    """A white rough conductor reflects at most all light (single scattering loses some at
    high roughness, never gains): the mean sample weight is <= 1 and > 0.5."""
    material = fmt.ConductorMaterial(type="conductor", eta=(1e-4,) * 3, k=(1e4,) * 3, roughness=0.6)
    mean = check_sampler(material, direction(45.0))
    assert np.all(mean <= 1.0 + 1e-3) and np.all(mean > 0.5), mean


@pytest.mark.parametrize("roughness", [0.0, 0.3, 1.0])
def test_white_plastic_albedo_is_at_most_one(roughness):
    """A white plastic's directional albedo (the mean sample weight) is at most 1 at every angle,
    within four standard errors; at roughness 0 it is 1 (a smooth coat loses nothing: what it
    does not reflect reaches the base, and 1 - Fdr_int of the base's light leaves)."""
    material = fmt.PlasticMaterial(type="plastic", roughness=roughness, reflectance=(1.0,) * 3)
    kind, albedo, param = row(material)
    for theta in (0.0, 45.0, 80.0):
        _, weights, pdfs, _ = _sample_many(kind, albedo, param, direction(theta), True, 100_000, 2)
        w = np.where(pdfs[:, None] > 0, weights, 0.0)[:, 0]
        mean, se = w.mean(), w.std() / math.sqrt(w.size)
        assert mean <= 1.0 + 4.0 * se, (theta, mean, se)
        if roughness == 0.0:
            assert abs(mean - 1.0) < 4.0 * se + 1e-3, (theta, mean, se)


def smooth_fdr(eta: float, steps: int = 4096) -> float:
    """Oracle: the smooth interface's diffuse Fresnel reflectance ``2 * integral_0^1 F(mu, eta)
    mu dmu`` from the side where the relative index is ``eta`` (midpoint rule)."""
    mu = (np.arange(steps) + 0.5) / steps
    f = np.array([fr_dielectric.py_func(float(m), eta) for m in mu])
    return float(2.0 * np.sum(f * mu) / steps)


def hemispherical(alpha, eta, which, critical=None):
    """``2 * integral_0^1 A(mu) mu dmu`` of the interface's directional reflectance (``which``
    0) or transmittance (1), Gauss-Legendre split at ``critical``."""
    nodes, weights = gauss_legendre(materials.COAT_QUADRATURE)
    cuts = (0.0, 1.0) if critical is None else (0.0, critical, 1.0)
    total = 0.0
    for lo, hi in itertools.pairwise(cuts):
        for m, w in zip(*gauss_legendre(32, lo, hi), strict=True):
            total += 2.0 * w * m * ggx_dielectric_albedo(m, alpha, eta, nodes, weights)[which]
    return total


@pytest.mark.parametrize("alpha", [1e-3, 0.09, 0.5, 1.0])
def test_coat_quadrature_has_converged(monkeypatch, alpha):
    """The coat's tables at twice the quadrature nodes (both rules) change by less than 1e-4
    (transmittance) and 3e-4 (internal reflectance, under 0.1% of the base's light)."""
    table, fdr = coat_tables(alpha, 1.5)
    monkeypatch.setattr(materials, "COAT_QUADRATURE", 2 * materials.COAT_QUADRATURE)
    monkeypatch.setattr(
        materials, "COAT_CRITICAL_QUADRATURE", 2 * materials.COAT_CRITICAL_QUADRATURE
    )
    fine_table, fine_fdr = coat_tables.__wrapped__(alpha, 1.5)
    np.testing.assert_allclose(table, fine_table, rtol=0.0, atol=1e-4)
    assert abs(fdr - fine_fdr) < 3e-4


def test_coat_tables_reach_the_smooth_interface():
    """At the smallest alpha (1e-3) the coat is the smooth interface: internal reflectance
    the smooth Fdr (0.596 at ior 1.5), transmittance ``1 - F`` within 3e-4 below 86 degrees
    (the table's correction); only within a few degrees of grazing does the GGX coat (alpha
    tan(theta) no longer small) let more light through."""
    for ior in (1.2, 1.5, 2.5):
        table, fdr = coat_tables(materials.PLASTIC_MIN_ALPHA, ior)
        assert fdr == pytest.approx(smooth_fdr(1.0 / ior), abs=1e-4)
        assert np.abs(table[4:]).max() < 3e-4  # cos >= 4/63
        assert 0.0 < table[0] < 0.05


@pytest.mark.parametrize("alpha", [1e-3, 0.09, 0.5, 1.0])
def test_coat_transmittance_is_reciprocal(alpha):
    """The rough interface's transmission is reciprocal up to eta^2 (radiance compression), so
    the hemispherical transmittance from outside is eta^2 times the one from inside: a check
    of the refracted directions and masking of ``ggx_dielectric_albedo``. Single scattering
    never creates energy: R + T <= 1 from either side."""
    eta = 1.5
    critical = math.sqrt(1.0 - 1.0 / eta**2)
    outside = hemispherical(alpha, eta, 1)
    inside = hemispherical(alpha, 1.0 / eta, 1, critical)
    assert outside == pytest.approx(eta**2 * inside, rel=3e-4)
    nodes, weights = gauss_legendre(materials.COAT_QUADRATURE)
    for mu in np.linspace(0.01, 1.0, 25):
        for e in (eta, 1.0 / eta):
            r, t = ggx_dielectric_albedo(mu, alpha, e, nodes, weights)
            assert 0.0 <= r and 0.0 <= t and r + t <= 1.0 + 1e-6, (mu, e, r, t)


def test_coat_reflectance_is_the_specular_lobes_albedo():
    """The quadrature's reflectance equals the directional albedo of the plastic's specular
    lobe, ``F(wo.h) D(h) G / (4 cos_o)`` integrated over a fine (cos theta, phi) grid by an
    independent numpy implementation of GGX."""
    eta, alpha = 1.5, 0.25
    n_mu, n_phi = 800, 400
    mu = (np.arange(n_mu) + 0.5) / n_mu
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * np.pi
    mu, phi = np.meshgrid(mu, phi, indexing="ij")
    sin = np.sqrt(1.0 - mu * mu)
    wi = np.stack([sin * np.cos(phi), sin * np.sin(phi), mu], axis=-1)

    def lam(w):
        tan2 = (1.0 - w[..., 2] ** 2) / w[..., 2] ** 2
        return 0.5 * (np.sqrt(1.0 + alpha * alpha * tan2) - 1.0)

    nodes, weights = gauss_legendre(materials.COAT_QUADRATURE)
    for theta in (0.0, 45.0, 75.0):
        wo = np.array(direction(theta))
        h = wi + wo
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        cos_h = h[..., 2]
        d = alpha**2 / (np.pi * (cos_h**2 * (alpha**2 - 1.0) + 1.0) ** 2)
        g = 1.0 / (1.0 + lam(wi) + lam(wo))
        c = np.clip(h @ wo, 0.0, 1.0)
        ct = np.sqrt(1.0 - (1.0 - c * c) / eta**2)
        f = 0.5 * (((eta * c - ct) / (eta * c + ct)) ** 2 + ((c - eta * ct) / (c + eta * ct)) ** 2)
        grid = np.sum(f * d * g / (4.0 * wo[2])) * 2.0 * np.pi / (n_mu * n_phi)
        r, _ = ggx_dielectric_albedo(wo[2], alpha, eta, nodes, weights)
        assert r == pytest.approx(grid, rel=2e-3), theta


def test_smooth_plastic_keeps_the_smooth_coats_base():
    """The smooth plastic's base term (roughness 0, coat alpha 1e-3) is the smooth interface's
    ``R (1 - F(cos_i)) (1 - F(cos_o)) cos_i / (pi eta^2 (1 - Fdr))`` within 0.1% away from
    grazing: the tables changed rough plastics only."""
    material = fmt.PlasticMaterial(type="plastic", roughness=0.0, reflectance=(0.5, 0.5, 0.5))
    _, _, (param, full) = row(material)
    eta = param[bsdf.IOR]
    fdr = smooth_fdr(1.0 / eta)
    for cos_o in np.linspace(0.1, 1.0, 10):
        for cos_i in np.linspace(0.1, 1.0, 10):
            t_o = bsdf.coat_transmittance(param, full, cos_o)
            t_i = bsdf.coat_transmittance(param, full, cos_i)
            ours = t_i * t_o / (1.0 - param[bsdf.FDR_INT])
            smooth = (1.0 - fr_dielectric(cos_i, eta)) * (1.0 - fr_dielectric(cos_o, eta))
            assert ours == pytest.approx(smooth / (1.0 - fdr), rel=1e-3)


def test_fresnel_dielectric_values():
    """Normal incidence ((eta-1)/(eta+1))^2; 1 beyond the critical angle; symmetric in the
    sense F(cos_i, eta) = F(cos_t, 1/eta) for the refracted angle."""
    assert fr_dielectric(1.0, 1.5) == pytest.approx(0.04)
    critical = math.asin(1.0 / 1.5)
    assert fr_dielectric(math.cos(critical) - 1e-6, 1.0 / 1.5) == 1.0
    cos_i = math.cos(math.radians(50.0))
    sin_t = math.sin(math.radians(50.0)) / 1.5
    cos_t = math.sqrt(1.0 - sin_t * sin_t)
    assert fr_dielectric(cos_i, 1.5) == pytest.approx(fr_dielectric(cos_t, 1.0 / 1.5))


def test_fresnel_conductor_matches_complex_arithmetic():
    """The real-arithmetic conductor Fresnel equals the textbook complex formula."""
    for eta, k in ((0.2, 3.9), (1.1, 0.0), (2.5, 1.0)):
        for cos_i in (1.0, 0.7, 0.3, 0.05):
            n = complex(eta, k)
            sin2 = 1.0 - cos_i * cos_i
            cos_t = np.sqrt(1.0 - sin2 / (n * n))
            rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
            rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
            expected = 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)
            assert fr_conductor(cos_i, eta, k) == pytest.approx(expected, rel=1e-9)


def test_conductor_reflectance_mapping():
    """A conductor given by its colour reflects exactly that colour at normal incidence."""
    for r in (0.04, 0.5, 0.9, 0.99):
        eta, k = conductor_index_from_reflectance(r)
        assert fr_conductor(1.0, eta, k) == pytest.approx(r, rel=1e-9)


def test_smooth_fdr_oracle():
    """The oracle above: glass's (eta 1.5) hemispherical Fresnel reflectance is about 0.092
    outside, and 1 - (1 - 0.092) / 1.5^2 inside (energy balance through the interface)."""
    outside = smooth_fdr(1.5)
    inside = smooth_fdr(1.0 / 1.5)
    assert outside == pytest.approx(0.0918, abs=5e-4)
    assert inside == pytest.approx(1.0 - (1.0 - outside) / 1.5**2, abs=1e-4)


def test_dielectric_chooses_reflection_with_probability_fresnel():
    """Smooth glass: reflection with probability F and weight 1, transmission with weight
    1/eta^2 in the direction Snell's law gives; from inside past the critical angle, always
    reflection."""
    kind, albedo, param = row(fmt.DielectricMaterial(type="dielectric", ior=1.5))
    wo = direction(40.0)
    dirs, weights, pdfs, deltas = _sample_many(kind, albedo, param, wo, True, 20_000, 4)
    assert deltas.all()
    f = fr_dielectric(wo[2], 1.5)
    reflected = dirs[:, 2] > 0
    assert abs(reflected.mean() - f) < 4 * math.sqrt(f * (1 - f) / 20_000)
    np.testing.assert_allclose(weights[reflected], 1.0)
    np.testing.assert_allclose(weights[~reflected], 1.0 / 2.25)
    np.testing.assert_allclose(pdfs[reflected], f)
    np.testing.assert_allclose(dirs[reflected], [[-wo[0], -wo[1], wo[2]]] * reflected.sum())
    t = dirs[~reflected][0]
    sin_i = math.sqrt(1.0 - wo[2] ** 2)
    assert math.sqrt(1.0 - t[2] ** 2) == pytest.approx(sin_i / 1.5)
    # From inside (back side), beyond the critical angle: total internal reflection.
    grazing = direction(60.0)
    dirs, weights, _, _ = _sample_many(kind, albedo, param, grazing, False, 1000, 5)
    assert (dirs[:, 2] > 0).all()
    np.testing.assert_allclose(weights, 1.0)


def test_mirror_and_smooth_conductor_are_delta():
    """The mirror reflects into the mirror direction with weight = reflectance; a conductor of
    roughness 0 does too, with weight F(cos); neither answers light samples."""
    wo = direction(35.0)
    for material in (
        fmt.MirrorMaterial(type="mirror", reflectance=(0.9, 0.8, 0.7)),
        fmt.ConductorMaterial(type="conductor", reflectance=(0.9, 0.8, 0.7)),
    ):
        kind, albedo, param = row(material)
        assert bsdf.bsdf_is_delta(kind, param[0])
        wi, weight, pdf, delta = bsdf.bsdf_sample(
            kind, albedo, *param, N, wo, True, True, 0.5, 0.5, 0.5
        )
        assert delta and pdf == 1.0
        np.testing.assert_allclose(wi, (-wo[0], -wo[1], wo[2]), atol=1e-15)
        f, p = bsdf.bsdf_eval(kind, albedo, *param, N, wo, wi)
        assert f == (0.0, 0.0, 0.0) and p == 0.0
        if material.type == "mirror":
            assert weight == (0.9, 0.8, 0.7)
        else:
            assert weight[0] > weight[1] > weight[2] > 0.7
