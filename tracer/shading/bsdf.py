"""BSDFs, dispatched on the material kind column (a closed set of variants, as pbrt does).

Directions are world space and unit length; ``n`` is the geometric normal turned toward the
outgoing direction ``wo`` (the side the path arrived from), and ``front`` says whether that is
the surface's front side (it decides which way a dielectric refracts). Each kind answers the
same questions: ``bsdf_eval`` (f * |cos| and the sampling density, for light samples),
``bsdf_sample`` (a direction, the weight f * |cos| / pdf and the pdf) and ``bsdf_is_delta``.

*Delta* lobes (mirror, smooth dielectric, smooth conductor) reflect or refract into a single
direction: ``bsdf_eval`` returns zero for them (a light sample can never hit that direction),
``bsdf_sample`` flags them, and the integrator counts emission found through them with MIS
weight 1 (no light sample could have found it). pdfs of delta samples are discrete
probabilities (the lobe's selection probability), never solid-angle densities.

Per-material parameters are a row of ``PARAM_COLUMNS`` float64 values (see
``tracer.shading.materials`` for how scene materials fill them): kernels pass its first ``PARAMS``
as the tuple ``param`` and the whole row as ``row``, from which a plastic reads its coat's table.
``albedo`` is the base colour, with the texture applied: the reflectance of diffuse, mirror and
plastic surfaces, and for a conductor a tint multiplying its Fresnel term (white without a
texture).
Formulas and references: docs/materials.md.
"""

from tracer.kernel.jit import jit
from tracer.maths.vecmath import coordinate_system, dot, to_world
from tracer.shading.fresnel import fr_conductor, fr_dielectric, refract_local
from tracer.shading.microfacet import (
    ggx_d,
    ggx_g,
    ggx_g1,
    ggx_reflection_pdf,
    ggx_sample_visible_normal,
    half_vector,
    reflect_local,
)
from tracer.shading.sampling import (
    INV_PI,
    square_to_cosine_hemisphere,
    square_to_cosine_hemisphere_pdf,
)

DIFFUSE = 0
MIRROR = 1
DIELECTRIC = 2
CONDUCTOR = 3
PLASTIC = 4
MATERIAL_KINDS = {
    "diffuse": DIFFUSE,
    "mirror": MIRROR,
    "dielectric": DIELECTRIC,
    "conductor": CONDUCTOR,
    "plastic": PLASTIC,
}

PARAMS = 8
"""Scalar columns of the parameter table (the ``param`` tuple). Layout per kind (unused
columns are 0):

- dielectric: ``IOR`` the index inside over outside, ``SIGMA`` (3) the absorption coefficient;
- conductor: ``ALPHA`` (GGX), ``ETA`` (3) and ``K`` (3), the complex index per channel;
- plastic: ``ALPHA``, ``IOR`` of the coat, ``FDR_INT`` the rough coat's internal diffuse
  reflectance, ``SPECULAR_WEIGHT`` the specular lobe's share of samples before the coat's
  reflectance.
"""
ALPHA = 0
IOR = 1
SIGMA = 2
ETA = 2
K = 5
FDR_INT = 2
SPECULAR_WEIGHT = 3

COAT_NODES = 64
"""Entries of a plastic's coat table: at ``cos = j / (COAT_NODES - 1)``, the rough coat's
transmittance minus the smooth interface's ``1 - F(cos)``, interpolated linearly between."""
COAT_TABLE = PARAMS
"""First column of the coat table in a parameter row (zeros for other kinds)."""
PARAM_COLUMNS = PARAMS + COAT_NODES

SMOOTH_ALPHA = 1e-3
"""Below this GGX alpha a conductor is treated as perfectly smooth (pbrt-v4's
``EffectivelySmooth``)."""

ZERO3 = (0.0, 0.0, 0.0)


@jit
def diffuse_eval(albedo, n, wi):
    """Lambertian f * cos for incident direction ``wi``; zero below the surface."""
    cos_i = dot(n, wi)
    if cos_i <= 0.0:
        return (0.0, 0.0, 0.0)
    k = cos_i * INV_PI
    return (albedo[0] * k, albedo[1] * k, albedo[2] * k)


@jit
def diffuse_pdf(n, wi):
    return square_to_cosine_hemisphere_pdf(dot(n, wi))


@jit
def diffuse_sample(albedo, n, u1, u2):
    """Cosine-weighted ``wi``; returns ``(wi, weight, pdf)`` with weight = f * cos / pdf."""
    local = square_to_cosine_hemisphere(u1, u2)
    s, t = coordinate_system(n)
    wi = to_world(local, s, t, n)
    pdf = square_to_cosine_hemisphere_pdf(local[2])
    if pdf <= 0.0:
        return wi, (0.0, 0.0, 0.0), 0.0
    return wi, albedo, pdf


@jit
def bsdf_is_delta(kind, param):
    """Whether the material scatters only into discrete directions (no light sampling)."""
    if kind == MIRROR or kind == DIELECTRIC:
        return True
    return kind == CONDUCTOR and param[ALPHA] < SMOOTH_ALPHA


@jit
def bsdf_needs_lobe_choice(kind):
    """Whether ``bsdf_sample`` uses its lobe-selection uniform ``u0``."""
    return kind == DIELECTRIC or kind == PLASTIC


@jit
def conductor_fresnel(param, cos_i):
    return (
        fr_conductor(cos_i, param[ETA], param[K]),
        fr_conductor(cos_i, param[ETA + 1], param[K + 1]),
        fr_conductor(cos_i, param[ETA + 2], param[K + 2]),
    )


@jit
def conductor_eval_local(param, wo, wi):
    """Rough conductor f * cos and pdf, local frame."""
    if wo[2] <= 0.0 or wi[2] <= 0.0:
        return ZERO3, 0.0
    alpha = param[ALPHA]
    h = half_vector(wo, wi)
    d = ggx_d(h, alpha)
    g = ggx_g(wo, wi, alpha)
    f = conductor_fresnel(param, dot(wo, h))
    k = d * g / (4.0 * wo[2])
    return (f[0] * k, f[1] * k, f[2] * k), ggx_g1(wo, alpha) * d / (4.0 * wo[2])


@jit
def coat_transmittance(param, row, cos_theta):
    """Share of light arriving at ``cos_theta`` that the plastic's rough coat lets through
    (single scattering, in either direction): ``1 - F(cos)`` of the smooth interface plus the
    coat table's correction, interpolated linearly."""
    x = cos_theta * (COAT_NODES - 1)
    j = min(int(x), COAT_NODES - 2)
    w = x - j
    correction = (1.0 - w) * row[COAT_TABLE + j] + w * row[COAT_TABLE + j + 1]
    return min(1.0, max(0.0, 1.0 - fr_dielectric(cos_theta, param[IOR]) + correction))


@jit
def plastic_specular_probability(param, t_o):
    """Share of plastic samples that go to the specular lobe when the coat transmits ``t_o``
    toward ``wo`` (Mitsuba's ``roughplastic``: the coat's reflectance ``1 - t_o`` times the
    lobes' mean-albedo weight)."""
    w = param[SPECULAR_WEIGHT]
    p_spec = (1.0 - t_o) * w
    total = p_spec + t_o * (1.0 - w)
    return p_spec / total if total > 0.0 else 1.0


@jit
def plastic_eval_local(albedo, param, row, wo, wi):
    """Coated diffuse f * cos and pdf, local frame: a GGX dielectric specular lobe plus the
    base seen through the rough coat (Mitsuba's ``roughplastic``)."""
    if wo[2] <= 0.0 or wi[2] <= 0.0:
        return ZERO3, 0.0
    alpha = param[ALPHA]
    eta = param[IOR]
    h = half_vector(wo, wi)
    d = ggx_d(h, alpha)
    spec = fr_dielectric(dot(wo, h), eta) * d * ggx_g(wo, wi, alpha) / (4.0 * wo[2])
    t_o = coat_transmittance(param, row, wo[2])
    t_i = coat_transmittance(param, row, wi[2])
    k = t_i * t_o * wi[2] * INV_PI / ((1.0 - param[FDR_INT]) * eta * eta)
    f = (spec + albedo[0] * k, spec + albedo[1] * k, spec + albedo[2] * k)
    p_spec = plastic_specular_probability(param, t_o)
    pdf = p_spec * ggx_g1(wo, alpha) * d / (4.0 * wo[2]) + (1.0 - p_spec) * wi[2] * INV_PI
    return f, pdf


@jit
def bsdf_eval(kind, albedo, param, row, n, wo, wi):
    """``(f * |cos(n, wi)|, pdf)`` of the non-delta lobes for light arriving from ``wi``.

    The pdf is the solid-angle density with which ``bsdf_sample`` picks ``wi``; delta-only
    materials return zeros. ``param`` is the material's scalar parameters (a tuple), ``row``
    its whole parameter row (an array).
    """
    if kind == DIFFUSE:
        return diffuse_eval(albedo, n, wi), diffuse_pdf(n, wi)
    if kind == CONDUCTOR and param[ALPHA] >= SMOOTH_ALPHA:
        s, t = coordinate_system(n)
        wo_l = (dot(s, wo), dot(t, wo), dot(n, wo))
        wi_l = (dot(s, wi), dot(t, wi), dot(n, wi))
        f, pdf = conductor_eval_local(param, wo_l, wi_l)
        return (f[0] * albedo[0], f[1] * albedo[1], f[2] * albedo[2]), pdf
    if kind == PLASTIC:
        s, t = coordinate_system(n)
        wo_l = (dot(s, wo), dot(t, wo), dot(n, wo))
        wi_l = (dot(s, wi), dot(t, wi), dot(n, wi))
        return plastic_eval_local(albedo, param, row, wo_l, wi_l)
    return ZERO3, 0.0


@jit
def bsdf_sample(kind, albedo, param, row, n, wo, front, refraction, u0, u1, u2):
    """Sample an incident direction: ``(wi, weight, pdf, delta)``.

    ``weight`` is f * |cos| / pdf (the throughput factor), ``pdf`` the solid-angle density
    (or, for a delta lobe, its discrete selection probability). A failed sample has pdf 0.
    ``u0`` chooses a lobe (dielectric, plastic); ``u1, u2`` place the direction.
    ``refraction`` False drops dielectric transmission (the ``refraction`` effect switched off):
    the surface then only reflects, with weight F.
    """
    if kind == DIFFUSE:
        wi, weight, pdf = diffuse_sample(albedo, n, u1, u2)
        return wi, weight, pdf, False
    cos_o = dot(n, wo)
    if kind == MIRROR:
        c = 2.0 * cos_o
        wi = (c * n[0] - wo[0], c * n[1] - wo[1], c * n[2] - wo[2])
        return wi, albedo, 1.0, True
    if kind == CONDUCTOR and param[ALPHA] < SMOOTH_ALPHA:
        c = 2.0 * cos_o
        wi = (c * n[0] - wo[0], c * n[1] - wo[1], c * n[2] - wo[2])
        f = conductor_fresnel(param, cos_o)
        return wi, (f[0] * albedo[0], f[1] * albedo[1], f[2] * albedo[2]), 1.0, True
    s, t = coordinate_system(n)
    wo_l = (dot(s, wo), dot(t, wo), cos_o)
    if kind == DIELECTRIC:
        eta = param[IOR] if front else 1.0 / param[IOR]
        f = fr_dielectric(cos_o, eta)
        if not refraction:
            c = 2.0 * cos_o
            wi = (c * n[0] - wo[0], c * n[1] - wo[1], c * n[2] - wo[2])
            return wi, (f, f, f), 1.0, True
        if u0 < f:
            c = 2.0 * cos_o
            wi = (c * n[0] - wo[0], c * n[1] - wo[1], c * n[2] - wo[2])
            return wi, (1.0, 1.0, 1.0), f, True
        wi_l, ok = refract_local(wo_l, eta)
        if not ok:  # only when f == 1, which u0 < 1 always chose above
            return wo, ZERO3, 0.0, True
        # Radiance is compressed entering a denser medium (pbrt-v4: divide by eta^2).
        scale = 1.0 / (eta * eta)
        return to_world(wi_l, s, t, n), (scale, scale, scale), 1.0 - f, True
    if kind == CONDUCTOR:
        alpha = param[ALPHA]
        if wo_l[2] <= 0.0:
            return wo, ZERO3, 0.0, False
        m = ggx_sample_visible_normal(wo_l, alpha, u1, u2)
        wi_l = reflect_local(wo_l, m)
        if wi_l[2] <= 0.0:
            return wo, ZERO3, 0.0, False
        f = conductor_fresnel(param, dot(wo_l, m))
        k = ggx_g(wo_l, wi_l, alpha) / ggx_g1(wo_l, alpha)
        pdf = ggx_reflection_pdf(wo_l, wi_l, alpha)
        weight = (f[0] * k * albedo[0], f[1] * k * albedo[1], f[2] * k * albedo[2])
        return to_world(wi_l, s, t, n), weight, pdf, False
    if kind == PLASTIC:
        if wo_l[2] <= 0.0:
            return wo, ZERO3, 0.0, False
        t_o = coat_transmittance(param, row, wo_l[2])
        if u0 < plastic_specular_probability(param, t_o):
            m = ggx_sample_visible_normal(wo_l, param[ALPHA], u1, u2)
            wi_l = reflect_local(wo_l, m)
        else:
            wi_l = square_to_cosine_hemisphere(u1, u2)
        if wi_l[2] <= 0.0:
            return wo, ZERO3, 0.0, False
        f, pdf = plastic_eval_local(albedo, param, row, wo_l, wi_l)
        if not pdf > 0.0:
            return wo, ZERO3, 0.0, False
        return to_world(wi_l, s, t, n), (f[0] / pdf, f[1] / pdf, f[2] / pdf), pdf, False
    return wo, ZERO3, 0.0, False


@jit
def bsdf_albedo(kind, albedo, param):
    """The colour a debug ``albedo`` image shows: the reflectance (textured), white for
    dielectrics, and for conductors the Fresnel reflectance at normal incidence times the
    tint."""
    if kind == DIELECTRIC:
        return (1.0, 1.0, 1.0)
    if kind == CONDUCTOR:
        f = conductor_fresnel(param, 1.0)
        return (f[0] * albedo[0], f[1] * albedo[1], f[2] * albedo[2])
    return albedo
