"""Unidirectional path tracing with next-event estimation, MIS and Russian roulette.

``render_pixels`` renders pixel blocks of lines [y0, y1) of a frame. Every random number is
drawn from the counter-based RNG keyed by (seed, frame, pixel, sample index) at a fixed dimension
per path vertex, so a pixel's value never depends on the split of the frame or on threads.

``max_depth`` counts path vertices after the camera (Mitsuba's convention): 1 shows only
emitters seen directly, 2 is direct lighting, 8 allows up to seven bounces.

The path loop lives inside ``render_pixels`` rather than in a function of its own: numba's
inliner deep-copies an inlined function's whole body, and copying the path code (with the
traversals it contains) cost half of the kernel's compile time.
"""

import numpy as np

from tracer.borrow import borrowed
from tracer.bsdf import diffuse_eval, diffuse_pdf, diffuse_sample
from tracer.camera import primary_ray
from tracer.jit import jit, jit_inline
from tracer.lights import emission_mean, sample_light
from tracer.rng import pixel_key, sample_key, uniform, uniform2
from tracer.sampling import power_heuristic
from tracer.scene_arrays import borrow_scene
from tracer.scene_intersect import (
    material_of,
    offset_distance,
    scene_closest,
    scene_occluded,
    spawn,
    surface,
)
from tracer.vecmath import dot, max_component, sub

PIXEL_BLOCK = 32
"""Consecutive pixels a thread renders before skipping to its next block."""

DIMS_PER_VERTEX = 8
"""Random dimensions reserved per path vertex: light choice (+0), light point (+1, two 32-bit
uniforms), BSDF direction (+2, two), Russian roulette (+3), four spare. Dimension 0 jitters the
pixel position (two)."""


@jit_inline
def light_sample(s, k, p_o, n_o, dist, p, ng, n, albedo, key, dim):
    """Next-event estimation at a path vertex: sample an emissive triangle, and return the
    MIS-weighted contribution it would make (before the path throughput) and the shadow ray
    ``(origin, direction)`` that decides it (``t`` up to ``shadow_t_max``); a zero contribution
    needs no shadow ray. The caller traces it: traversals stay out of inlined helpers, whose
    bodies numba copies at every inlining.

    ``(k, p_o, n_o, dist)`` locate the vertex for spawning rays, ``p`` and ``ng`` are its
    render-space position and geometric normal, ``n`` the normal facing the viewer.
    """
    u1, u2 = uniform2(key, dim + 1)
    lk, l_mat, q_o, q_err, nl_o, q, n_l = sample_light(s, uniform(key, dim), u1, u2)
    none = (0.0, 0.0, 0.0)
    to_light = sub(q, p)
    dist2 = dot(to_light, to_light)
    if not dist2 > 0.0:
        return none, p, to_light
    inv_dist = 1.0 / np.sqrt(dist2)
    wi = (to_light[0] * inv_dist, to_light[1] * inv_dist, to_light[2] * inv_dist)
    cos_l = -dot(n_l, wi)
    if cos_l == 0.0 or (cos_l < 0.0 and not s.mat_two_sided[l_mat]):
        return none, p, to_light  # the light faces away
    f = diffuse_eval(albedo, n, wi)
    if f[0] == 0.0 and f[1] == 0.0 and f[2] == 0.0:
        return none, p, to_light
    # Light density in solid angle: (mean emission / total power) dist^2 / |cos_l| (area cancels).
    p_light = emission_mean(s.mat_emission, l_mat) / s.light_total[0] * dist2 / abs(cos_l)
    w = power_heuristic(p_light, diffuse_pdf(n, wi))
    s_o = spawn(s, k, p_o, n_o, dist, ng, wi)
    dist_l = offset_distance(s, lk, q_o, q_err, nl_o)
    s_t = spawn(s, lk, q_o, nl_o, dist_l, n_l, (-wi[0], -wi[1], -wi[2]))
    g = w / p_light
    contribution = (
        f[0] * s.mat_emission[l_mat, 0] * g,
        f[1] * s.mat_emission[l_mat, 1] * g,
        f[2] * s.mat_emission[l_mat, 2] * g,
    )
    return contribution, s_o, sub(s_t, s_o)


@jit
def render_pixels(
    scene,
    camera,
    width,
    height,
    y0,
    y1,
    sample_start,
    spp,
    max_depth,
    rr_depth,
    seed,
    frame,
    shadow_t_max,
    first,
    stride,
    stack_node,
    stack_t,
    out_rgb,
    out_cost,
):
    """Render pixel blocks ``first, first + stride, ...`` of lines [y0, y1).

    ``scene`` is a ``SceneArrays``. ``out_rgb`` float32 (y1-y0, W, 3) gets the mean of samples
    [sample_start, sample_start + spp) of each pixel, ``out_cost`` int64 (y1-y0, W) the work
    spent on it. Threads call this with the same stride and different ``first``: interleaved
    blocks of ``PIXEL_BLOCK`` pixels balance lines of very different cost, and keep threads off
    each other's cache lines. ``stack_node`` (int32) and ``stack_t`` (float64) are this thread's
    traversal stacks.

    Every array is borrowed (:mod:`tracer.borrow`) before the loops, so the inlined path code
    passes them around without atomic reference counting.
    """
    s = borrow_scene(scene)
    camera = borrowed(camera)
    stack_node = borrowed(stack_node)
    stack_t = borrowed(stack_t)
    has_lights = s.light_cdf.shape[0] > 0
    n_pix = (y1 - y0) * width
    for block in range(first, (n_pix + PIXEL_BLOCK - 1) // PIXEL_BLOCK, stride):
        for i in range(block * PIXEL_BLOCK, min(n_pix, (block + 1) * PIXEL_BLOCK)):
            row = i // width
            x = i - row * width
            y = y0 + row
            p_key = pixel_key(seed, frame, y * width + x)
            acc = (0.0, 0.0, 0.0)
            cost = 0
            for sample in range(sample_start, sample_start + spp):
                key = sample_key(p_key, sample)
                jx, jy = uniform2(key, 0)
                o, d = primary_ray(camera, width, height, x + jx, y + jy)
                L = (0.0, 0.0, 0.0)
                beta = (1.0, 1.0, 1.0)
                p_bsdf_prev = 0.0
                depth = 1
                while True:
                    # Trace the ray to the next path vertex; a miss sees the sky.
                    k, j, t, b0, b1, b2, c = scene_closest(s, o, d, np.inf, stack_node, stack_t)
                    cost += c
                    if k < 0:
                        L = (L[0] + beta[0] * s.sky[0], L[1] + beta[1] * s.sky[1],
                             L[2] + beta[2] * s.sky[2])  # fmt: skip
                        break
                    mat = material_of(s, k, j)
                    p_o, err_o, n_o, p, ng = surface(s, k, j, b0, b1, b2)
                    cos_o = -dot(ng, d)
                    if cos_o == 0.0 or (cos_o < 0.0 and not s.mat_two_sided[mat]):
                        break  # grazing, or the back of a one-sided surface: no light at all
                    n = ng if cos_o > 0.0 else (-ng[0], -ng[1], -ng[2])

                    # Add emission, MIS-weighted against light sampling after the first vertex.
                    e_mean = emission_mean(s.mat_emission, mat)
                    if e_mean > 0.0:
                        w = 1.0
                        if depth > 1 and has_lights:
                            p_light = e_mean / s.light_total[0] * t * t / abs(cos_o)
                            w = power_heuristic(p_bsdf_prev, p_light)
                        L = (L[0] + beta[0] * s.mat_emission[mat, 0] * w,
                             L[1] + beta[1] * s.mat_emission[mat, 1] * w,
                             L[2] + beta[2] * s.mat_emission[mat, 2] * w)  # fmt: skip
                    if depth >= max_depth:
                        break

                    # Sample a light (next-event estimation).
                    dist = offset_distance(s, k, p_o, err_o, n_o)
                    albedo = (np.float64(s.mat_albedo[mat, 0]), np.float64(s.mat_albedo[mat, 1]),
                              np.float64(s.mat_albedo[mat, 2]))  # fmt: skip
                    dim = 1 + (depth - 1) * DIMS_PER_VERTEX
                    if has_lights:
                        Ld, s_o, s_d = light_sample(s, k, p_o, n_o, dist, p, ng, n, albedo, key,
                                                    dim)  # fmt: skip
                        if Ld[0] > 0.0 or Ld[1] > 0.0 or Ld[2] > 0.0:
                            blocked, c = scene_occluded(s, s_o, s_d, shadow_t_max, stack_node)
                            cost += c
                            if not blocked:
                                L = (L[0] + beta[0] * Ld[0], L[1] + beta[1] * Ld[1],
                                     L[2] + beta[2] * Ld[2])  # fmt: skip

                    # Sample the BSDF for the next direction and update the throughput.
                    u1, u2 = uniform2(key, dim + 2)
                    wi, weight, pdf = diffuse_sample(albedo, n, u1, u2)
                    if pdf <= 0.0:
                        break
                    beta = (beta[0] * weight[0], beta[1] * weight[1], beta[2] * weight[2])
                    p_bsdf_prev = pdf
                    depth += 1

                    # Russian roulette: survive with probability q and divide by it (unbiased).
                    if depth > rr_depth:
                        q = min(0.95, max_component(beta))
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
