"""Unidirectional path tracing with next-event estimation, MIS and Russian roulette, and the
Whitted variant (direct light at diffuse and glossy surfaces, recursion through delta lobes).

The kernel (``path_kernel``, built four ways) renders pixel blocks of a pixel run [p0, p1) of
a frame: pixels in row-major order (index ``y * width + x``), of which lines [y0, y1) are the
run [y0 * width, y1 * width). Every random number is drawn from the counter-based RNG keyed by
(seed, frame, pixel, sample index) at a fixed dimension per path vertex, so a pixel's value
never depends on the split of the frame or on threads.

``max_depth`` counts path vertices after the camera (Mitsuba's convention): 1 shows only
emitters seen directly, 2 is direct lighting, 8 allows up to seven bounces.

Every step is guarded by the effect plan's flags (``tracer.integrators.flags``): a step the
scene does not need is skipped. Without material effects every surface is Lambertian and the
kernel never reads the kind column; with them, Lambertian hits still take the direct Lambertian
code and only other kinds go through the BSDF dispatch.

The path loop lives inside the kernel rather than in a function of its own: numba's
inliner deep-copies an inlined function's whole body, and copying the path code (with the
traversals it contains) cost half of the kernel's compile time.
"""

import math

import numpy as np

from tracer.compiled.arrays import borrow_scene
from tracer.geometry.scene_intersect import (
    material_of,
    offset_distance,
    scene_closest,
    scene_occluded,
    spawn,
    surface,
)
from tracer.integrators import flags
from tracer.kernel.borrow import borrowed
from tracer.kernel.jit import jit, jit_inline
from tracer.maths.rng import pixel_key, sample_key, uniform, uniform2
from tracer.maths.vecmath import dot, max_component, sub
from tracer.shading.bsdf import (
    DIELECTRIC,
    DIFFUSE,
    IOR,
    SIGMA,
    bsdf_eval,
    bsdf_is_delta,
    bsdf_needs_lobe_choice,
    bsdf_sample,
    diffuse_eval,
    diffuse_pdf,
    diffuse_sample,
)
from tracer.shading.camera import LENS_DIM, camera_sample_ray
from tracer.shading.lights import (
    TRIANGLE,
    emission_mean,
    environment_radiance,
    pick_light,
    sample_distant_or_point,
    sample_triangle,
)
from tracer.shading.sampling import power_heuristic
from tracer.shading.textures import textured_albedo

PIXEL_BLOCK = 32
"""Consecutive pixels a thread renders before skipping to its next block."""

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


@jit_inline
def material_param(mat_param, mat):
    """The scalar parameters of row ``mat`` of the parameter table as a tuple (its first
    ``bsdf.PARAMS`` values)."""
    return (mat_param[mat, 0], mat_param[mat, 1], mat_param[mat, 2], mat_param[mat, 3],
            mat_param[mat, 4], mat_param[mat, 5], mat_param[mat, 6], mat_param[mat, 7])  # fmt: skip


@jit_inline
def triangle_light(s, e, u1, u2, p):
    """A point on the emissive triangle of light entry ``e`` (``u1, u2``) as seen from the
    render-space point ``p``: ``(ok, wi, Le, p_light, lk, q_o, q_err, nl_o, n_l)``, the unit
    direction toward it, its emitted radiance, the solid-angle density of this sample
    (selection probability included), and what spawning the shadow ray's far end needs. ``ok``
    is False when the point cannot light ``p`` (it faces away, or coincides with ``p``)."""
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
    # Light density in solid angle: (mean emission / total power) dist^2 / |cos_l|.
    p_light = emission_mean(s.mat_emission, l_mat) / s.light_total[0] * dist2 / abs(cos_l)
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


def path_kernel(materials: bool, lights: bool):
    """The path kernel compiled with or without the material dispatch (``materials``) and
    the point, spot, sun and sky code (``lights``).

    Both are constants of the returned kernel (closure variables, which numba freezes): the
    code they switch off is removed before type inference, so a scene of Lambertian surfaces
    and emissive triangles (the Cornell box) never compiles the BSDFs or the other lights.
    Every other effect of the plan is a runtime flag. ``docs/effects.md`` measures this
    against one kernel for every plan and against one kernel per plan.
    """

    def trace_pixels(
        scene,
        camera,
        width,
        height,
        p0,
        p1,
        sample_start,
        spp,
        max_depth,
        rr_depth,
        seed,
        frame,
        shadow_t_max,
        mode,
        plan,
        first,
        stride,
        stack_node,
        stack_t,
        out_rgb,
        out_cost,
        out_rays,
    ):
        """Render pixel blocks ``first, first + stride, ...`` of the pixel run [p0, p1).

        ``scene`` is a ``SceneArrays``. The outputs have a row per line the run touches (row 0 is
        line ``p0 // width``; pixels outside the run are left untouched): ``out_rgb`` float32
        (rows, W, 3) gets the mean of samples [sample_start, sample_start + spp) of each pixel,
        ``out_cost`` int64 (rows, W) the work spent on it, ``out_rays`` int64 (rows, W) the rays
        traced for it (one per traversal: camera, continuation and shadow rays). ``mode`` is
        ``PATH`` or ``WHITTED``; ``plan`` the effect flags (``tracer.integrators.flags``).
        Threads call this with the same stride and different ``first``: interleaved blocks of
        ``PIXEL_BLOCK`` pixels balance lines of very different cost, and keep threads off each
        other's cache lines. ``stack_node`` (int32) and ``stack_t`` (float64) are this thread's
        traversal stacks.

        Every array is borrowed (:mod:`tracer.kernel.borrow`) before the loops, so the inlined path
        code passes them around without atomic reference counting.
        """
        s = borrow_scene(scene)
        camera = borrowed(camera)
        stack_node = borrowed(stack_node)
        stack_t = borrowed(stack_t)
        has_lights = s.light_cdf.shape[0] > 0 and (plan & flags.LIGHT_SAMPLES) != 0
        mis = mode == PATH and (plan & flags.NO_MIS) == 0
        nee_only = mode == PATH and not mis  # emitters that BSDF rays hit are light samples
        general = (plan & flags.MATERIAL_EFFECTS) != 0
        refraction = (plan & flags.REFRACTION) != 0
        # Where ``materials`` or ``lights`` is False, the branches below that test it first are
        # removed before type inference: their callees are never compiled into this kernel.
        y_first = p0 // width  # the line of row 0 of the outputs
        n_blocks = (p1 - p0 + PIXEL_BLOCK - 1) // PIXEL_BLOCK
        for block in range(first, n_blocks, stride):
            start = p0 + block * PIXEL_BLOCK
            for i in range(start, min(p1, start + PIXEL_BLOCK)):  # i = y * width + x
                y = i // width
                x = i - y * width
                row = y - y_first
                p_key = pixel_key(seed, frame, i)
                acc = (0.0, 0.0, 0.0)
                cost = 0
                rays = 0
                for sample in range(sample_start, sample_start + spp):
                    key = sample_key(p_key, sample)
                    o, d = camera_sample_ray(camera, width, height, x, y, key)
                    L = (0.0, 0.0, 0.0)
                    beta = (1.0, 1.0, 1.0)
                    eta_scale = 1.0  # the eta^2 that radiance leaving the media gets back
                    p_bsdf_prev = 0.0
                    delta_prev = False
                    depth = 1
                    while True:
                        # Trace the ray to the next path vertex; a miss sees the sky and suns.
                        k, j, t, b0, b1, b2, c = scene_closest(s, o, d, np.inf, stack_node, stack_t)
                        cost += c
                        rays += 1
                        if k < 0:
                            if lights and plan & (flags.SKY | flags.SUN):
                                weighted = (mode == PATH and depth > 1 and not delta_prev
                                            and has_lights)  # fmt: skip
                                # Without MIS a zero BSDF density weighs sampled lights to 0.
                                p_w = p_bsdf_prev if mis else 0.0
                                Le = environment_radiance(s.light_data, s.light_env, s.sky,
                                                          s.sky_image, s.sky_rows, s.sky_cols, d,
                                                          p_w, weighted)  # fmt: skip
                                L = (L[0] + beta[0] * Le[0], L[1] + beta[1] * Le[1],
                                     L[2] + beta[2] * Le[2])  # fmt: skip
                            break
                        mat = material_of(s, k, j)
                        p_o, err_o, n_o, p, ng = surface(s, k, j, b0, b1, b2)
                        cos_o = -dot(ng, d)
                        if cos_o == 0.0 or (cos_o < 0.0 and not s.mat_two_sided[mat]):
                            break  # grazing, or the back of a one-sided surface: no light at all
                        front = cos_o > 0.0
                        n = ng if front else (-ng[0], -ng[1], -ng[2])

                        # Absorb along a segment inside a dielectric (Beer-Lambert).
                        if materials and plan & flags.ABSORPTION and not front:
                            if s.mat_kind[mat] == DIELECTRIC:
                                sigma = (s.mat_param[mat, SIGMA], s.mat_param[mat, SIGMA + 1],
                                         s.mat_param[mat, SIGMA + 2])  # fmt: skip
                                beta = (beta[0] * math.exp(-sigma[0] * t),
                                        beta[1] * math.exp(-sigma[1] * t),
                                        beta[2] * math.exp(-sigma[2] * t))  # fmt: skip

                        # Add emission, MIS-weighted against light sampling after a non-delta
                        # bounce (left to light sampling alone without MIS).
                        if plan & flags.AREA_LIGHTS:
                            e_mean = emission_mean(s.mat_emission, mat)
                            if e_mean > 0.0:
                                w = 1.0
                                if depth > 1 and has_lights and mis and not delta_prev:
                                    p_light = e_mean / s.light_total[0] * t * t / abs(cos_o)
                                    w = power_heuristic(p_bsdf_prev, p_light)
                                elif depth > 1 and has_lights and nee_only and not delta_prev:
                                    w = 0.0
                                L = (L[0] + beta[0] * s.mat_emission[mat, 0] * w,
                                     L[1] + beta[1] * s.mat_emission[mat, 1] * w,
                                     L[2] + beta[2] * s.mat_emission[mat, 2] * w)  # fmt: skip
                        if depth >= max_depth:
                            break

                        # The material at the vertex.
                        dist = offset_distance(s, k, p_o, err_o, n_o)
                        albedo = (np.float64(s.mat_albedo[mat, 0]),
                                  np.float64(s.mat_albedo[mat, 1]),
                                  np.float64(s.mat_albedo[mat, 2]))  # fmt: skip
                        if plan & flags.TEXTURES:
                            albedo = textured_albedo(s, mat, albedo, k, j, b0, b1, b2)
                        wo = (-d[0], -d[1], -d[2])
                        kind = DIFFUSE
                        param = NO_PARAM
                        delta = False
                        if materials and general:
                            kind = s.mat_kind[mat]
                            if kind != DIFFUSE:
                                param = material_param(s.mat_param, mat)
                                delta = bsdf_is_delta(kind, param)
                        dim = 1 + (depth - 1) * DIMS_PER_VERTEX

                        # Sample a light (next-event estimation); delta lobes never meet one.
                        # Pick one (by power), then a point or direction on it.
                        if has_lights and not delta:
                            e = pick_light(s, uniform(key, dim))
                            u1, u2 = uniform2(key, dim + 1)
                            other = lights and s.light_kind[e] != TRIANGLE
                            if lights and other:
                                wi, q_l, finite, le, p_light, delta_l = sample_distant_or_point(
                                    s.light_data, s.sky, s.sky_image, s.sky_rows, s.sky_cols,
                                    s.light_kind[e], s.light_tri[e], p, u1, u2,
                                )  # fmt: skip
                                ok = p_light > 0.0
                            else:
                                ok, wi, le, p_light, lk, q_o, q_err, nl_o, n_l = triangle_light(
                                    s, e, u1, u2, p
                                )
                                delta_l = False
                            # The BSDF toward it: f cos, and its density for MIS.
                            f = (0.0, 0.0, 0.0)
                            p_bsdf = 0.0
                            if ok:
                                if materials and kind != DIFFUSE:
                                    f, p_bsdf = bsdf_eval(kind, albedo, param, s.mat_param[mat],
                                                          n, wo, wi)  # fmt: skip
                                else:
                                    f = diffuse_eval(albedo, n, wi)
                                    if mis and not delta_l:
                                        p_bsdf = diffuse_pdf(n, wi)
                            if f[0] > 0.0 or f[1] > 0.0 or f[2] > 0.0:
                                w = 1.0
                                if mis and not delta_l:
                                    w = power_heuristic(p_light, p_bsdf)
                                g = w / p_light
                                Ld = (f[0] * le[0] * g, f[1] * le[1] * g, f[2] * le[2] * g)
                                # The shadow ray that decides it.
                                if lights and other:
                                    s_o = spawn(s, k, p_o, n_o, dist, ng, wi)
                                    s_d = sub(q_l, s_o) if finite else wi
                                    t_max = shadow_t_max if finite else np.inf
                                else:
                                    s_o, s_d = triangle_shadow_ray(
                                        s, k, p_o, n_o, dist, ng, wi, lk, q_o, q_err, nl_o, n_l
                                    )
                                    t_max = shadow_t_max
                                blocked = False
                                if plan & flags.SHADOWS:
                                    blocked, c = scene_occluded(s, s_o, s_d, t_max, stack_node)
                                    cost += c
                                    rays += 1
                                if not blocked:
                                    L = (L[0] + beta[0] * Ld[0], L[1] + beta[1] * Ld[1],
                                         L[2] + beta[2] * Ld[2])  # fmt: skip
                        if mode == WHITTED and not delta:
                            break  # Whitted: light at diffuse and glossy surfaces is direct only
                        if depth + 1 >= max_depth and not plan & flags.EMITTER_HITS:
                            break  # the last ray could only find emission, and nothing emits

                        # Sample the BSDF for the next direction and update the throughput.
                        u1, u2 = uniform2(key, dim + 2)
                        if materials and kind != DIFFUSE:
                            u0 = uniform(key, dim + 4) if bsdf_needs_lobe_choice(kind) else 0.0
                            wi, weight, pdf, delta_prev = bsdf_sample(kind, albedo, param,
                                                                      s.mat_param[mat], n, wo,
                                                                      front, refraction, u0, u1,
                                                                      u2)  # fmt: skip
                        else:
                            wi, weight, pdf = diffuse_sample(albedo, n, u1, u2)
                            delta_prev = False
                        if pdf <= 0.0:
                            break
                        beta = (beta[0] * weight[0], beta[1] * weight[1], beta[2] * weight[2])
                        if beta[0] == 0.0 and beta[1] == 0.0 and beta[2] == 0.0:
                            break  # nothing more can reach the camera along this path
                        if kind == DIELECTRIC and dot(wi, n) * dot(wo, n) < 0.0:
                            eta = param[IOR] if front else 1.0 / param[IOR]
                            eta_scale *= eta * eta  # refracted: beta carries 1 / eta^2
                        p_bsdf_prev = pdf
                        depth += 1
                        if nee_only and has_lights and depth >= max_depth and not delta_prev:
                            break  # the last vertex's emission would count 0 without MIS

                        # Russian roulette: survive with probability q and divide by it
                        # (unbiased), q from the throughput the path has once out of any glass
                        # (pbrt-v4's etaScale): inside, beta is low by the 1 / eta^2 of entering.
                        if depth > rr_depth:
                            q = min(0.95, max_component(beta) * eta_scale)
                            if uniform(key, dim + 3) >= q:
                                break
                            beta = (beta[0] / q, beta[1] / q, beta[2] / q)

                        o = spawn(s, k, p_o, n_o, dist, ng, wi)
                        d = wi
                    acc = (acc[0] + L[0], acc[1] + L[1], acc[2] + L[2])
                out_rgb[row, x, 0] = acc[0] / spp
                out_rgb[row, x, 1] = acc[1] / spp
                out_rgb[row, x, 2] = acc[2] / spp
                out_cost[row, x] = cost
                out_rays[row, x] = rays

    trace_pixels.__qualname__ = f"trace_pixels_{'m' if materials else 'l'}{'o' if lights else 't'}"
    return jit(trace_pixels)


KERNELS = {(m, o): path_kernel(m, o) for m in (False, True) for o in (False, True)}
"""The path kernel's four builds, by (materials, lights); ``kernel_for`` picks one for a plan."""


def kernel_for(plan: int):
    """The build of the path kernel that a plan needs: with the material dispatch if it has a
    material effect (or the ``flags.MATERIAL_BUILD`` switch), with the point/spot/sun/sky
    code if it has one of those lights."""
    materials = (plan & (flags.MATERIAL_EFFECTS | flags.MATERIAL_BUILD)) != 0
    lights = (plan & (flags.POINT_LIGHTS | flags.SUN | flags.SKY)) != 0
    return KERNELS[(materials, lights)]
