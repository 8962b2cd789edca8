"""BSDFs, dispatched on the material kind column (a closed set of variants, as pbrt does).

Directions are world space; ``n`` is the geometric normal turned toward the outgoing direction.
Each kind answers the same three questions: ``eval`` (f * |cos|), ``sample`` and ``pdf``.
"""

from tracer.jit import jit
from tracer.sampling import INV_PI, square_to_cosine_hemisphere, square_to_cosine_hemisphere_pdf
from tracer.vecmath import coordinate_system, dot, to_world

DIFFUSE = 0
MATERIAL_KINDS = {"diffuse": DIFFUSE}


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
