"""Unidirectional path tracing with next-event estimation, MIS and Russian roulette.

``render_kernel`` renders lines [y0, y1) of a frame. Every random number is drawn from the
counter-based RNG keyed by (seed, frame, pixel, sample index) at a fixed dimension per path
vertex, so a pixel's value never depends on the split of the frame or on threads.

``max_depth`` counts path vertices after the camera (Mitsuba's convention): 1 shows only
emitters seen directly, 2 is direct lighting, 8 allows up to seven bounces.
"""

import numpy as np

from tracer.borrow import borrowed
from tracer.bsdf import diffuse_eval, diffuse_pdf, diffuse_sample
from tracer.camera import primary_ray
from tracer.intersect import geometric_normal, hit_point, intersect, occluded, offset_ray_origin
from tracer.jit import jit, jit_inline
from tracer.lights import emission_mean, sample_emitter
from tracer.rng import pixel_key, sample_key, uniform, uniform2
from tracer.sampling import power_heuristic
from tracer.vecmath import dot, max_component, sub

PIXEL_BLOCK = 32
"""Consecutive pixels a thread renders before skipping to its next block."""

DIMS_PER_VERTEX = 8
"""Random dimensions reserved per path vertex: light choice (+0), light point (+1, two 32-bit
uniforms), BSDF direction (+2, two), Russian roulette (+3), four spare. Dimension 0 jitters the
pixel position (two)."""


@jit_inline
def trace_path(
    node_bounds,
    node_child,
    tri_verts,
    tri_material,
    mat_albedo,
    mat_emission,
    mat_two_sided,
    light_tri,
    light_cdf,
    light_total,
    o,
    d,
    key,
    max_depth,
    rr_depth,
    shadow_t_max,
    stack_node,
    stack_t,
):
    """Radiance along the camera ray (o, d). Returns ``(L, cost)``."""
    L0 = 0.0
    L1 = 0.0
    L2 = 0.0
    beta = (1.0, 1.0, 1.0)
    p_bsdf_prev = 0.0
    depth = 1
    cost = 0
    n_lights = light_tri.shape[0]
    while True:
        # Trace the ray to the next path vertex.
        j, t, b0, b1, b2, c = intersect(
            node_bounds, node_child, tri_verts, o, d, np.inf, stack_node, stack_t
        )
        cost += c
        if j < 0:
            break
        mat = tri_material[j]
        ng, area = geometric_normal(tri_verts, j)
        cos_o = -dot(ng, d)
        if cos_o == 0.0 or (cos_o < 0.0 and not mat_two_sided[mat]):
            break  # grazing, or the back of a one-sided surface: it neither emits nor reflects
        n = ng if cos_o > 0.0 else (-ng[0], -ng[1], -ng[2])

        # Add emission, MIS-weighted against light sampling after the first vertex.
        e_mean = emission_mean(mat_emission, mat)
        if e_mean > 0.0:
            w = 1.0
            if depth > 1 and n_lights > 0:
                p_light = e_mean * area / light_total[0] * t * t / (abs(cos_o) * area)
                w = power_heuristic(p_bsdf_prev, p_light)
            L0 += beta[0] * mat_emission[mat, 0] * w
            L1 += beta[1] * mat_emission[mat, 1] * w
            L2 += beta[2] * mat_emission[mat, 2] * w
        if depth >= max_depth:
            break

        p, p_err = hit_point(tri_verts, j, b0, b1, b2)
        albedo = (
            np.float64(mat_albedo[mat, 0]),
            np.float64(mat_albedo[mat, 1]),
            np.float64(mat_albedo[mat, 2]),
        )
        dim = 1 + (depth - 1) * DIMS_PER_VERTEX

        # Sample a light (next-event estimation) and trace a shadow ray to it.
        if n_lights > 0:
            u1, u2 = uniform2(key, dim + 1)
            u = (uniform(key, dim), u1, u2)
            lj, q, q_err, n_l, l_area, p_select = sample_emitter(
                light_tri, light_cdf, light_total, tri_verts, tri_material, mat_emission, u
            )
            to_light = sub(q, p)
            dist2 = dot(to_light, to_light)
            if dist2 > 0.0:
                inv_dist = 1.0 / np.sqrt(dist2)
                wi = (to_light[0] * inv_dist, to_light[1] * inv_dist, to_light[2] * inv_dist)
                cos_l = -dot(n_l, wi)
                l_mat = tri_material[lj]
                if cos_l != 0.0 and (cos_l > 0.0 or mat_two_sided[l_mat]):
                    f = diffuse_eval(albedo, n, wi)
                    if f[0] > 0.0 or f[1] > 0.0 or f[2] > 0.0:
                        p_light = p_select * dist2 / (abs(cos_l) * l_area)
                        w = power_heuristic(p_light, diffuse_pdf(n, wi))
                        n_back = (-wi[0], -wi[1], -wi[2])
                        s_o = offset_ray_origin(p, p_err, ng, wi)
                        s_t = offset_ray_origin(q, q_err, n_l, n_back)
                        blocked, c = occluded(
                            node_bounds,
                            node_child,
                            tri_verts,
                            s_o,
                            sub(s_t, s_o),
                            shadow_t_max,
                            stack_node,
                        )
                        cost += c
                        if not blocked:
                            k = w / p_light
                            L0 += beta[0] * f[0] * mat_emission[l_mat, 0] * k
                            L1 += beta[1] * f[1] * mat_emission[l_mat, 1] * k
                            L2 += beta[2] * f[2] * mat_emission[l_mat, 2] * k

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
            q_survive = min(0.95, max_component(beta))
            if uniform(key, dim + 3) >= q_survive:
                break
            beta = (beta[0] / q_survive, beta[1] / q_survive, beta[2] / q_survive)

        o = offset_ray_origin(p, p_err, ng, wi)
        d = wi
    return (L0, L1, L2), cost


@jit
def render_pixels(
    node_bounds,
    node_child,
    tri_verts,
    tri_material,
    mat_albedo,
    mat_emission,
    mat_two_sided,
    light_tri,
    light_cdf,
    light_total,
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

    ``out_rgb`` float32 (y1-y0, W, 3) gets the mean of samples [sample_start, sample_start + spp)
    of each pixel, ``out_cost`` int64 (y1-y0, W) the work spent on it. Threads call this with the
    same stride and different ``first``: interleaved blocks of ``PIXEL_BLOCK`` pixels balance lines
    of very different cost, and keep threads off each other's cache lines. ``stack_node`` (int32)
    and ``stack_t`` (float64) are this thread's traversal stacks.

    Every array is borrowed (:mod:`tracer.borrow`) before the loops, so the inlined path code
    passes them around without atomic reference counting.
    """
    node_bounds = borrowed(node_bounds)
    node_child = borrowed(node_child)
    tri_verts = borrowed(tri_verts)
    tri_material = borrowed(tri_material)
    mat_albedo = borrowed(mat_albedo)
    mat_emission = borrowed(mat_emission)
    mat_two_sided = borrowed(mat_two_sided)
    light_tri = borrowed(light_tri)
    light_cdf = borrowed(light_cdf)
    light_total = borrowed(light_total)
    camera = borrowed(camera)
    stack_node = borrowed(stack_node)
    stack_t = borrowed(stack_t)
    n_pix = (y1 - y0) * width
    for block in range(first, (n_pix + PIXEL_BLOCK - 1) // PIXEL_BLOCK, stride):
        for i in range(block * PIXEL_BLOCK, min(n_pix, (block + 1) * PIXEL_BLOCK)):
            row = i // width
            x = i - row * width
            y = y0 + row
            p_key = pixel_key(seed, frame, y * width + x)
            acc0 = 0.0
            acc1 = 0.0
            acc2 = 0.0
            cost = 0
            for s in range(sample_start, sample_start + spp):
                key = sample_key(p_key, s)
                jx, jy = uniform2(key, 0)
                o, d = primary_ray(camera, width, height, x + jx, y + jy)
                L, c = trace_path(
                    node_bounds,
                    node_child,
                    tri_verts,
                    tri_material,
                    mat_albedo,
                    mat_emission,
                    mat_two_sided,
                    light_tri,
                    light_cdf,
                    light_total,
                    o,
                    d,
                    key,
                    max_depth,
                    rr_depth,
                    shadow_t_max,
                    stack_node,
                    stack_t,
                )
                acc0 += L[0]
                acc1 += L[1]
                acc2 += L[2]
                cost += c
            out_rgb[row, x, 0] = acc0 / spp
            out_rgb[row, x, 1] = acc1 / spp
            out_rgb[row, x, 2] = acc2 / spp
            out_cost[row, x] = cost
