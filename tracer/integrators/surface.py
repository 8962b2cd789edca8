"""Integrators that look only at the surface a camera ray hits: ambient occlusion and the debug
outputs (albedo, normal, depth).

Ambient occlusion follows Demoullin (thesis ch. 3): from the first hit, ``ao_samples`` rays in
cosine-weighted directions about the normal facing the camera, each an any-hit query of length
``ao_distance`` (a fraction of the scene's bounding-box diagonal); the value is the fraction
that escape, an estimate of ``1/pi * integral V(w) cos dw``. The debug outputs are the first
hit's base colour with its texture (white for dielectrics; for conductors their reflectance at
normal incidence), its normal facing the camera mapped to
``0.5 n + 0.5``, and the distance along the camera ray. Rays that hit nothing give 0. Every
output averages its camera samples like the path tracer (box filter, same jitter and lens).

Random dimensions: 0 the pixel jitter, ``camera.LENS_DIM`` the lens, ``1 + i`` the i-th
occlusion ray.
"""

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
from tracer.integrators.normals import surface_normal
from tracer.integrators.path import PIXEL_BLOCK
from tracer.kernel.borrow import borrowed
from tracer.kernel.jit import jit
from tracer.maths.rng import pixel_key, sample_key, uniform2
from tracer.maths.vecmath import coordinate_system, dot, to_world
from tracer.shading.bsdf import bsdf_albedo
from tracer.shading.camera import (
    LENS_DIM as LENS_DIM,  # the lens dimension, shared with the path tracer
)
from tracer.shading.camera import camera_sample_ray
from tracer.shading.sampling import square_to_cosine_hemisphere
from tracer.shading.textures import textured_albedo

AO = 0
ALBEDO = 1
NORMAL = 2
DEPTH = 3
"""The outputs of ``render_surface`` (the integrators ``ao``, ``albedo``, ``normal``, ``depth``)."""


@jit
def render_surface(
    scene,
    camera,
    width,
    height,
    p0,
    p1,
    sample_start,
    spp,
    counts,
    seed,
    frame,
    output,
    ao_samples,
    ao_length,
    textures,
    normal_plan,
    first,
    stride,
    stack_node,
    stack_t,
    out_rgb,
    out_cost,
    out_rays,
    out_aov,
):
    """Render ``output`` (``AO``, ``ALBEDO``, ``NORMAL`` or ``DEPTH``) for pixel blocks
    ``first, first + stride, ...`` of the pixel run [p0, p1); arguments and outputs as the path
    kernel's (``tracer.integrators.path.path_kernel``), plus ``ao_samples`` occlusion rays per
    camera sample of length ``ao_length`` (render-space units), and ``textures``: whether the
    albedo output applies base-colour textures (the effect plan's ``TEXTURES``), and
    ``normal_plan``: the plan's ``SHADING_NORMALS`` and ``NORMAL_MAPS`` bits, which shading
    normal the normal output and occlusion use. ``out_rays``
    gets the rays traced per pixel: each camera ray, and each occlusion ray (``AO`` only).
    ``out_aov`` is untouched: AOVs come from the path integrators' paths."""
    s = borrow_scene(scene)
    camera = borrowed(camera)
    stack_node = borrowed(stack_node)
    stack_t = borrowed(stack_t)
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
            n_samples = spp if counts.shape[0] == 0 else counts[i]
            for sample in range(sample_start, sample_start + n_samples):
                key = sample_key(p_key, sample)
                o, d = camera_sample_ray(camera, width, height, x, y, key)
                k, j, t, b0, b1, b2, c = scene_closest(s, o, d, np.inf, stack_node, stack_t)
                cost += c
                rays += 1
                if k < 0:
                    continue
                mat = material_of(s, k, j)
                p_o, err_o, n_o, _, ng = surface(s, k, j, b0, b1, b2)
                front = dot(ng, d) < 0.0
                n = ng if front else (-ng[0], -ng[1], -ng[2])
                smooth = False
                if normal_plan:
                    smooth, ns = surface_normal(s, mat, k, j, b0, b1, b2, ng, normal_plan)
                    n = ns if front else (-ns[0], -ns[1], -ns[2])
                if output == DEPTH:
                    value = (t, t, t)
                elif output == NORMAL:
                    value = (0.5 * n[0] + 0.5, 0.5 * n[1] + 0.5, 0.5 * n[2] + 0.5)
                elif output == ALBEDO:
                    albedo = (np.float64(s.mat_albedo[mat, 0]), np.float64(s.mat_albedo[mat, 1]),
                              np.float64(s.mat_albedo[mat, 2]))  # fmt: skip
                    if textures:
                        albedo = textured_albedo(s, mat, albedo, k, j, b0, b1, b2)
                    value = bsdf_albedo(s.mat_kind[mat], albedo, s.mat_param[mat])
                else:
                    dist = offset_distance(s, k, p_o, err_o, n_o)
                    u_s, u_t = coordinate_system(n)
                    open_count = 0
                    for r in range(ao_samples):
                        u1, u2 = uniform2(key, 1 + r)
                        w = to_world(square_to_cosine_hemisphere(u1, u2), u_s, u_t, n)
                        if smooth and dot(w, ng) * dot(d, ng) >= 0.0:
                            continue  # below the geometric surface: the surface itself blocks
                        origin = spawn(s, k, p_o, n_o, dist, ng, w)
                        blocked, c = scene_occluded(s, origin, w, ao_length, stack_node)
                        cost += c
                        rays += 1
                        if not blocked:
                            open_count += 1
                    ao = open_count / ao_samples
                    value = (ao, ao, ao)
                acc = (acc[0] + value[0], acc[1] + value[1], acc[2] + value[2])
            out_rgb[row, x, 0] = acc[0] / n_samples
            out_rgb[row, x, 1] = acc[1] / n_samples
            out_rgb[row, x, 2] = acc[2] / n_samples
            out_cost[row, x] = cost
            out_rays[row, x] = rays
