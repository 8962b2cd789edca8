"""One path vertex of the path tracer: what the single-ray kernel (``tracer.integrators.path``)
and the stream kernel (``tracer.integrators.stream``) do between two traversals.

``vertex_shader(materials, lights)`` builds :func:`shade` for a kernel build. Given the closest
hit of a path's ray and the path's state, it adds what the vertex emits (or what the sky sends
to a ray that escaped), prepares the light sample's shadow ray with the radiance it would add,
and samples the continuation ray. It traces nothing: the caller traces the shadow ray, adds the
radiance if the ray is unblocked, and traces the continuation. Both kernels run this one
function, so the arithmetic of a path is the same whichever kernel traces it: their images are
bit-identical.

A path's state is ``(L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n)``: the
radiance so far, the throughput, the eta^2 that radiance leaving the media gets back, the
density of the BSDF sample that led here (for MIS), whether that sample was a delta lobe, the
path's vertex count, and the previous vertex's point and shading normal (the light tree's
probability of an emitter a BSDF sample hits depends on them).
"""

import math

import numpy as np

from tracer.geometry.scene_intersect import material_of, offset_distance, spawn, surface
from tracer.integrators import flags
from tracer.integrators.normals import surface_normal
from tracer.kernel.jit import jit_inline
from tracer.maths.rng import uniform, uniform2
from tracer.maths.vecmath import dot, max_component, sub
from tracer.shading.bsdf import (
    DIELECTRIC,
    DIFFUSE,
    IOR,
    SIGMA,
    bsdf_albedo,
    bsdf_eval,
    bsdf_is_delta,
    bsdf_needs_lobe_choice,
    bsdf_sample,
    diffuse_eval,
    diffuse_pdf,
    diffuse_sample,
)
from tracer.shading.camera import LENS_DIM
from tracer.shading.light_tree import NOT_TREE, tree_hit_density, tree_pick
from tracer.shading.lights import (
    TRIANGLE,
    emission_mean,
    environment_radiance,
    pick_light,
    sample_distant_or_point,
    sample_triangle,
)
from tracer.shading.sampling import power_heuristic
from tracer.shading.shading_normals import bent_normal, geometric_side, terminator
from tracer.shading.textures import textured_albedo

DIMS_PER_VERTEX = 8
"""Random dimensions reserved per path vertex: light choice (+0), light point (+1, two 32-bit
uniforms), BSDF direction (+2, two), Russian roulette (+3), BSDF lobe choice (+4), three
spare. Dimension 0 jitters the pixel position (two); ``LENS_DIM`` places the lens sample."""
if LENS_DIM != DIMS_PER_VERTEX:  # the lens takes the first vertex's last spare dimension
    raise ImportError("camera.LENS_DIM must be the first vertex's last spare dimension")

PATH = 0
WHITTED = 1
"""Kernel modes: ``PATH`` (NEE + MIS; ``direct`` is a path of at most two vertices; with the
plan's ``flags.NO_MIS`` switch, NEE without MIS) and ``WHITTED`` (no MIS; a path continues
only through delta lobes)."""

NO_PARAM = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
BLACK = (0.0, 0.0, 0.0)
NO_RAY = (0.0, 0.0, 0.0)
NO_AOV = (False, BLACK, NO_RAY, NO_RAY)
"""What a vertex gives the AOVs when the path no longer records them."""


@jit_inline
def camera_path():
    """The state of a path that leaves the camera."""
    return BLACK, (1.0, 1.0, 1.0), 1.0, 0.0, False, 1, NO_RAY, NO_RAY


@jit_inline
def material_param(mat_param, mat):
    """The scalar parameters of row ``mat`` of the parameter table as a tuple (its first
    ``bsdf.PARAMS`` values)."""
    return (mat_param[mat, 0], mat_param[mat, 1], mat_param[mat, 2], mat_param[mat, 3],
            mat_param[mat, 4], mat_param[mat, 5], mat_param[mat, 6], mat_param[mat, 7])  # fmt: skip


@jit_inline
def triangle_light(s, e, u1, u2, p, sel):
    """A point on the emissive triangle of light entry ``e`` (``u1, u2``) as seen from the
    render-space point ``p``: ``(ok, wi, Le, p_light, lk, q_o, q_err, nl_o, n_l)``, the unit
    direction toward it, its emitted radiance, the solid-angle density of this sample
    (selection probability included: ``sel`` per unit area, or by power when negative), and
    what spawning the shadow ray's far end needs. ``ok`` is False when the point cannot light
    ``p`` (it faces away, or coincides with ``p``)."""
    lk, l_mat, q_o, q_err, nl_o, q, n_l = sample_triangle(s, e, u1, u2)
    to_light = sub(q, p)
    dist2 = dot(to_light, to_light)
    if not dist2 > 0.0:
        return False, to_light, (0.0, 0.0, 0.0), 0.0, lk, q_o, q_err, nl_o, n_l
    inv_dist = 1.0 / np.sqrt(dist2)
    wi = (to_light[0] * inv_dist, to_light[1] * inv_dist, to_light[2] * inv_dist)
    cos_l = -dot(n_l, wi)
    if cos_l == 0.0 or (cos_l < 0.0 and not s.mat_two_sided[l_mat]):
        return False, wi, (0.0, 0.0, 0.0), 0.0, lk, q_o, q_err, nl_o, n_l  # it faces away
    # Light density in solid angle: (mean emission / total power) dist^2 / |cos_l| by power.
    if sel < 0.0:
        sel = emission_mean(s.mat_emission, l_mat) / s.light_total[0]
    p_light = sel * dist2 / abs(cos_l)
    le = (np.float64(s.mat_emission[l_mat, 0]), np.float64(s.mat_emission[l_mat, 1]),
          np.float64(s.mat_emission[l_mat, 2]))  # fmt: skip
    return True, wi, le, p_light, lk, q_o, q_err, nl_o, n_l


@jit_inline
def triangle_shadow_ray(s, k, p_o, n_o, dist, ng, wi, lk, q_o, q_err, nl_o, n_l):
    """The shadow ray ``(origin, direction)`` from a path vertex to a point on an emissive
    triangle, both ends spawned past their surfaces (``t`` up to ``shadow_t_max``)."""
    s_o = spawn(s, k, p_o, n_o, dist, ng, wi)
    dist_l = offset_distance(s, lk, q_o, q_err, nl_o)
    s_t = spawn(s, lk, q_o, nl_o, dist_l, n_l, (-wi[0], -wi[1], -wi[2]))
    return s_o, sub(s_t, s_o)


def vertex_shader(materials: bool, lights: bool):
    """:func:`shade` with or without the material dispatch, the surface detail and the light
    tree (``materials``: BSDFs, textures, shading normals, normal maps, tree picks) and the point,
    spot, sun and sky code (``lights``): constants of the returned function, so the code they
    switch off is never compiled into a kernel that inlines it."""

    def shade(s, key, d, k, j, t, b0, b1, b2, state, mode, plan, max_depth, rr_depth,
              shadow_t_max, record):  # fmt: skip
        """The vertex where the ray ``d`` of a path with ``state`` hit ``(k, j, t, b0, b1, b2)``
        (``scene_closest``'s hit; ``k < 0`` for a miss).

        Returns ``(go_on, state, o, wi, shadow, s_o, s_d, s_t_max, Ld, aov)``: whether the path
        goes on, its new state, its next ray (when it goes on), and whether a shadow ray
        ``(s_o, s_d)`` up to ``s_t_max`` decides a light sample that adds ``Ld`` to ``L`` when
        unblocked (whether or not the path goes on). With ``record`` (the path still looks for
        its AOVs' vertex), ``aov`` is what this hit gives the AOVs
        (``tracer.integrators.aov``): ``(final, colour, normal, point)``, where a non-delta
        vertex is ``final``, ``colour`` its albedo and ``normal`` its shading normal facing the
        ray, unbent; a delta vertex's ``colour`` tints what lies beyond it. ``point`` is the
        render-space hit point. The AOVs read the same surface evaluation as the shading, so
        its texture and normal look-ups are compiled once.
        """
        L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n = state
        has_lights = s.light_cdf.shape[0] > 0 and (plan & flags.LIGHT_SAMPLES) != 0
        mis = mode == PATH and (plan & flags.NO_MIS) == 0
        nee_only = mode == PATH and not mis  # emitters that BSDF rays hit are light samples
        general = (plan & flags.MATERIAL_EFFECTS) != 0
        refraction = (plan & flags.REFRACTION) != 0
        use_tree = (plan & flags.LIGHT_TREE) != 0 and s.light_tree_child.shape[0] > 0
        shadow = False
        s_o = NO_RAY
        s_d = NO_RAY
        s_t_max = 0.0
        Ld = BLACK
        aov = NO_AOV
        # A miss sees the sky and suns.
        if k < 0:
            if lights and plan & (flags.SKY | flags.SUN):
                weighted = mode == PATH and depth > 1 and not delta_prev and has_lights
                # Without MIS a zero BSDF density weighs sampled lights to 0.
                p_w = p_bsdf_prev if mis else 0.0
                Le = environment_radiance(s.light_data, s.light_env, s.sky, s.sky_image,
                                          s.sky_rows, s.sky_cols, d, p_w, weighted)  # fmt: skip
                L = (L[0] + beta[0] * Le[0], L[1] + beta[1] * Le[1], L[2] + beta[2] * Le[2])
            state = (L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n)
            return False, state, NO_RAY, NO_RAY, shadow, s_o, s_d, s_t_max, Ld, aov
        mat = material_of(s, k, j)
        p_o, err_o, n_o, p, ng = surface(s, k, j, b0, b1, b2)
        cos_o = -dot(ng, d)
        # Grazing, or the back of a one-sided surface: no light at all (the AOVs still see it).
        blind = cos_o == 0.0 or (cos_o < 0.0 and not s.mat_two_sided[mat])
        if blind and not record:
            state = (L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n)
            return False, state, NO_RAY, NO_RAY, shadow, s_o, s_d, s_t_max, Ld, aov
        front = cos_o > 0.0
        n = ng if front else (-ng[0], -ng[1], -ng[2])
        wo = (-d[0], -d[1], -d[2])
        # The shading normal (docs/materials.md, "Shading normals"): BSDFs are evaluated about
        # ``ns``; the geometric ``n`` keeps deciding sides.
        smooth = False
        ns = n
        if materials and plan & (flags.SHADING_NORMALS | flags.NORMAL_MAPS):
            smooth, ns = surface_normal(s, mat, k, j, b0, b1, b2, ng, plan)
            ns = ns if front else (-ns[0], -ns[1], -ns[2])
        aov_normal = ns
        if smooth and plan & flags.NORMAL_BENDING:
            ns = bent_normal(ns, n, wo)
        # Unbent, a viewer below the shading normal sees no scattered light (Mitsuba's rule).
        dark = materials and smooth and dot(wo, ns) <= 0.0

        # The material at the vertex, where it scatters or the AOVs look at it.
        albedo = BLACK
        kind = DIFFUSE
        param = NO_PARAM
        delta = False
        if record or not (blind or dark or depth >= max_depth):
            albedo = (np.float64(s.mat_albedo[mat, 0]), np.float64(s.mat_albedo[mat, 1]),
                      np.float64(s.mat_albedo[mat, 2]))  # fmt: skip
            if materials and plan & flags.TEXTURES:
                albedo = textured_albedo(s, mat, albedo, k, j, b0, b1, b2)
            if materials and general:
                kind = s.mat_kind[mat]
                if kind != DIFFUSE:
                    param = material_param(s.mat_param, mat)
                    delta = bsdf_is_delta(kind, param)
        if record:
            colour = albedo
            if materials and kind != DIFFUSE:
                colour = bsdf_albedo(kind, albedo, param)
            aov = (not delta, colour, aov_normal, p)
            if blind:
                state = (L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n)
                return False, state, NO_RAY, NO_RAY, shadow, s_o, s_d, s_t_max, Ld, aov

        # Absorb along a segment inside a dielectric (Beer-Lambert).
        if materials and plan & flags.ABSORPTION and not front:
            if s.mat_kind[mat] == DIELECTRIC:
                sigma = (s.mat_param[mat, SIGMA], s.mat_param[mat, SIGMA + 1],
                         s.mat_param[mat, SIGMA + 2])  # fmt: skip
                beta = (beta[0] * math.exp(-sigma[0] * t), beta[1] * math.exp(-sigma[1] * t),
                        beta[2] * math.exp(-sigma[2] * t))  # fmt: skip

        # Add emission, MIS-weighted against light sampling after a non-delta bounce (left to
        # light sampling alone without MIS).
        if plan & flags.AREA_LIGHTS:
            e_mean = emission_mean(s.mat_emission, mat)
            if e_mean > 0.0:
                w = 1.0
                if depth > 1 and has_lights and mis and not delta_prev:
                    if materials and use_tree:
                        sel = tree_hit_density(s.light_cdf, s.light_tree_nodes,
                                               s.light_tree_child, s.light_tree_bits,
                                               s.light_tree_area, s.light_tree_keys,
                                               s.light_tree_key_light, k, j, prev_p,
                                               prev_n)  # fmt: skip
                    else:
                        sel = e_mean / s.light_total[0]
                    p_light = sel * t * t / abs(cos_o)
                    w = power_heuristic(p_bsdf_prev, p_light)
                elif depth > 1 and has_lights and nee_only and not delta_prev:
                    w = 0.0
                L = (L[0] + beta[0] * s.mat_emission[mat, 0] * w,
                     L[1] + beta[1] * s.mat_emission[mat, 1] * w,
                     L[2] + beta[2] * s.mat_emission[mat, 2] * w)  # fmt: skip
        if depth >= max_depth or dark:
            state = (L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n)
            return False, state, NO_RAY, NO_RAY, shadow, s_o, s_d, s_t_max, Ld, aov
        dist = offset_distance(s, k, p_o, err_o, n_o)
        dim = 1 + (depth - 1) * DIMS_PER_VERTEX

        # Sample a light (next-event estimation); delta lobes never meet one. Pick one (by
        # power, or triangles with the light tree), then a point or direction on it.
        if has_lights and not delta:
            u0 = uniform(key, dim)
            e = NOT_TREE
            sel = -1.0
            if materials and use_tree:
                e, sel = tree_pick(s.light_cdf, s.light_tree_nodes, s.light_tree_child,
                                   s.light_tree_area, u0, p, ns)  # fmt: skip
            if e == NOT_TREE:
                e = pick_light(s, u0)
            picked = e >= 0
            e = max(e, 0)
            u1, u2 = uniform2(key, dim + 1)
            other = lights and s.light_kind[e] != TRIANGLE
            if lights and other:
                wi, q_l, finite, le, p_light, delta_l = sample_distant_or_point(
                    s.light_data, s.sky, s.sky_image, s.sky_rows, s.sky_cols, s.light_kind[e],
                    s.light_tri[e], p, u1, u2,
                )  # fmt: skip
                ok = p_light > 0.0
            else:
                ok, wi, le, p_light, lk, q_o, q_err, nl_o, n_l = triangle_light(
                    s, e, u1, u2, p, sel
                )
                ok = ok and picked
                delta_l = False
            # The BSDF toward it: f cos, and its density for MIS.
            f = (0.0, 0.0, 0.0)
            p_bsdf = 0.0
            if materials and ok and smooth and geometric_side(n, wo, wi) != 1:
                ok = False  # behind the geometric surface: no light leaks through it
            if ok:
                if materials and kind != DIFFUSE:
                    f, p_bsdf = bsdf_eval(kind, albedo, param, s.mat_param[mat], ns, wo, wi)
                else:
                    f = diffuse_eval(albedo, ns, wi)
                    if mis and not delta_l:
                        p_bsdf = diffuse_pdf(ns, wi)
                if materials and smooth and plan & flags.SHADOW_TERMINATOR:
                    g = terminator(ns, n, wi)
                    f = (f[0] * g, f[1] * g, f[2] * g)
            if f[0] > 0.0 or f[1] > 0.0 or f[2] > 0.0:
                w = 1.0
                if mis and not delta_l:
                    w = power_heuristic(p_light, p_bsdf)
                g = w / p_light
                Ld = (f[0] * le[0] * g, f[1] * le[1] * g, f[2] * le[2] * g)
                Ld = (beta[0] * Ld[0], beta[1] * Ld[1], beta[2] * Ld[2])
                # The shadow ray that decides it.
                if lights and other:
                    s_o = spawn(s, k, p_o, n_o, dist, ng, wi)
                    s_d = sub(q_l, s_o) if finite else wi
                    s_t_max = shadow_t_max if finite else np.inf
                else:
                    s_o, s_d = triangle_shadow_ray(
                        s, k, p_o, n_o, dist, ng, wi, lk, q_o, q_err, nl_o, n_l
                    )
                    s_t_max = shadow_t_max
                shadow = True
        state = (L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n)
        if mode == WHITTED and not delta:
            # Whitted: light at diffuse and glossy surfaces is direct only.
            return False, state, NO_RAY, NO_RAY, shadow, s_o, s_d, s_t_max, Ld, aov
        if depth + 1 >= max_depth and not plan & flags.EMITTER_HITS:
            # The last ray could only find emission, and nothing emits.
            return False, state, NO_RAY, NO_RAY, shadow, s_o, s_d, s_t_max, Ld, aov

        # Sample the BSDF for the next direction and update the throughput.
        u1, u2 = uniform2(key, dim + 2)
        if materials and kind != DIFFUSE:
            u0 = uniform(key, dim + 4) if bsdf_needs_lobe_choice(kind) else 0.0
            wi, weight, pdf, delta_prev = bsdf_sample(kind, albedo, param, s.mat_param[mat], ns,
                                                      wo, front, refraction, u0, u1,
                                                      u2)  # fmt: skip
        else:
            wi, weight, pdf = diffuse_sample(albedo, ns, u1, u2)
            delta_prev = False
        if materials and smooth and pdf > 0.0:
            # A reflection must stay on the viewer's side of the geometric surface and a
            # refraction cross it; a sample the shading normal sends the other way is lost.
            reflected = dot(wi, ns) * dot(wo, ns) > 0.0
            if geometric_side(n, wo, wi) != (1 if reflected else -1):
                pdf = 0.0
            elif reflected and not delta_prev and plan & flags.SHADOW_TERMINATOR:
                g = terminator(ns, n, wi)
                weight = (weight[0] * g, weight[1] * g, weight[2] * g)
        if pdf <= 0.0:
            return False, state, NO_RAY, NO_RAY, shadow, s_o, s_d, s_t_max, Ld, aov
        beta = (beta[0] * weight[0], beta[1] * weight[1], beta[2] * weight[2])
        state = (L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n)
        if beta[0] == 0.0 and beta[1] == 0.0 and beta[2] == 0.0:
            # Nothing more can reach the camera along this path.
            return False, state, NO_RAY, NO_RAY, shadow, s_o, s_d, s_t_max, Ld, aov
        if kind == DIELECTRIC and dot(wi, n) * dot(wo, n) < 0.0:
            eta = param[IOR] if front else 1.0 / param[IOR]
            eta_scale *= eta * eta  # refracted: beta carries 1 / eta^2
        p_bsdf_prev = pdf
        prev_p = p
        prev_n = ns
        depth += 1
        state = (L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n)
        if nee_only and has_lights and depth >= max_depth and not delta_prev:
            # The last vertex's emission would count 0 without MIS.
            return False, state, NO_RAY, NO_RAY, shadow, s_o, s_d, s_t_max, Ld, aov

        # Russian roulette: survive with probability q and divide by it (unbiased), q from the
        # throughput the path has once out of any glass (pbrt-v4's etaScale): inside, beta is
        # low by the 1 / eta^2 of entering.
        if depth > rr_depth:
            q = min(0.95, max_component(beta) * eta_scale)
            if uniform(key, dim + 3) >= q:
                return False, state, NO_RAY, NO_RAY, shadow, s_o, s_d, s_t_max, Ld, aov
            beta = (beta[0] / q, beta[1] / q, beta[2] / q)
        state = (L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n)
        o = spawn(s, k, p_o, n_o, dist, ng, wi)
        return True, state, o, wi, shadow, s_o, s_d, s_t_max, Ld, aov

    shade.__qualname__ = f"shade_{build_name(materials, lights)}"
    return jit_inline(shade)


BUILDS = [(m, o) for m in (False, True) for o in (False, True)]
"""The kernels' builds: (materials, lights)."""


def build_name(materials: bool, lights: bool) -> str:
    """A build's suffix of kernel names (their on-disk cache entries differ by it)."""
    return f"{'m' if materials else 'l'}{'o' if lights else 't'}"


SHADERS = {build: vertex_shader(*build) for build in BUILDS}
"""``shade`` for each of the kernel's builds, by (materials, lights)."""
