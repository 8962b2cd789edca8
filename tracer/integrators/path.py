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

What happens at a path vertex is ``tracer.integrators.vertex.shade`` (shared with the stream
kernel, ``tracer.integrators.stream``); the traversals stay in the kernel's own loop: numba's
inliner deep-copies an inlined function's whole body, and copying the traversals into the
vertex code cost half of the kernel's compile time.
"""

import numpy as np

from tracer.compiled.arrays import borrow_scene
from tracer.geometry.alpha_traversal import traversals
from tracer.geometry.scene_intersect import material_of, object_of, scene_closest, scene_occluded
from tracer.integrators import aov, flags
from tracer.integrators.vertex import BUILDS, SHADERS, build_name, camera_path
from tracer.kernel.borrow import borrowed
from tracer.kernel.jit import jit, with_globals
from tracer.maths.rng import pixel_key, sample_key
from tracer.shading.camera import camera_sample_ray

PIXEL_BLOCK = 32
"""Consecutive pixels a thread renders before skipping to its next block."""


def path_kernel(materials: bool, lights: bool):
    """The path kernel compiled with or without the material dispatch, the surface detail, the
    light tree and the alpha test (``materials``: BSDFs, textures, vertex normals, normal maps,
    tree picks, traversals that test alpha) and the point, spot, sun and sky code (``lights``).

    Both pick the build of the vertex shader the kernel inlines (``vertex.SHADERS``), where
    they are constants: the code they switch off is removed before type inference, so a scene
    of flat, untextured Lambertian surfaces and emissive triangles (the Cornell box) never
    compiles the BSDFs, the surface detail or the other lights.
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
        counts,
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
        out_aov,
    ):
        """Render pixel blocks ``first, first + stride, ...`` of the pixel run [p0, p1).

        ``scene`` is a ``SceneArrays``. The outputs have a row per line the run touches (row 0 is
        line ``p0 // width``; pixels outside the run are left untouched): ``out_rgb`` float32
        (rows, W, 3) gets the mean of samples [sample_start, sample_start + n) of each pixel, where
        ``n`` is ``spp``, or with a non-empty ``counts`` (int32, one per pixel of the frame)
        ``counts[i]`` for pixel ``i`` (adaptive sampling),
        ``out_cost`` int64 (rows, W) the work spent on it, ``out_rays`` int64 (rows, W) the rays
        traced for it (one per traversal: camera, continuation and shadow rays), and with the
        plan's ``flags.AOVS`` ``out_aov`` float32 (rows, W, ``aov.CHANNELS``) the mean of the
        samples' AOVs and the ids of the first sample's hit (``tracer.integrators.aov``;
        untouched without it). ``mode`` is ``vertex.PATH`` or ``vertex.WHITTED``; ``plan`` the
        effect flags (``integrators.flags``).
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
        y_first = p0 // width  # the line of row 0 of the outputs
        aovs = (plan & flags.AOVS) != 0
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
                a_albedo = (0.0, 0.0, 0.0)
                a_normal = (0.0, 0.0, 0.0)
                a_point = (0.0, 0.0, 0.0)
                a_depth = 0.0
                a_hits = 0
                a_object = -1
                a_material = -1
                n_samples = spp if counts.shape[0] == 0 else counts[i]
                for sample in range(sample_start, sample_start + n_samples):
                    key = sample_key(p_key, sample)
                    o, d = camera_sample_ray(camera, width, height, x, y, key)
                    state = camera_path()
                    aov_open = aovs
                    tint = (1.0, 1.0, 1.0)
                    while True:
                        k, j, t, b0, b1, b2, c = scene_closest(s, o, d, np.inf, stack_node, stack_t)
                        cost += c
                        rays += 1
                        first_hit = state[5] == 1
                        aov_open = aov_open and k >= 0
                        go_on, state, o, d, shadow, s_o, s_d, s_t_max, Ld, rec = shade(  # noqa: F821 (with_globals binds it)
                            s, key, d, k, j, t, b0, b1, b2, state, mode, plan, max_depth,
                            rr_depth, shadow_t_max, aov_open,
                        )  # fmt: skip
                        if aov_open:
                            final, colour, n, p = rec
                            if first_hit:  # the camera ray's hit
                                a_depth += t
                                a_point = (a_point[0] + p[0], a_point[1] + p[1], a_point[2] + p[2])
                                a_hits += 1
                                if sample == sample_start:
                                    a_object = object_of(s, k, j)
                                    a_material = material_of(s, k, j)
                            tint = (tint[0] * colour[0], tint[1] * colour[1], tint[2] * colour[2])
                            if final:
                                a_albedo = (a_albedo[0] + tint[0], a_albedo[1] + tint[1],
                                            a_albedo[2] + tint[2])  # fmt: skip
                                a_normal = (a_normal[0] + n[0], a_normal[1] + n[1],
                                            a_normal[2] + n[2])  # fmt: skip
                                aov_open = False
                        if shadow:
                            blocked = False
                            if plan & flags.SHADOWS:
                                blocked, c = scene_occluded(s, s_o, s_d, s_t_max, stack_node)
                                cost += c
                                rays += 1
                            if not blocked:
                                L = state[0]
                                L = (L[0] + Ld[0], L[1] + Ld[1], L[2] + Ld[2])
                                state = (L,) + state[1:]
                        if not go_on:
                            break
                    L = state[0]
                    acc = (acc[0] + L[0], acc[1] + L[1], acc[2] + L[2])
                out_rgb[row, x, 0] = acc[0] / n_samples
                out_rgb[row, x, 1] = acc[1] / n_samples
                out_rgb[row, x, 2] = acc[2] / n_samples
                out_cost[row, x] = cost
                out_rays[row, x] = rays
                if aovs:
                    for ch in range(3):
                        out_aov[row, x, aov.ALBEDO + ch] = a_albedo[ch] / n_samples
                        out_aov[row, x, aov.NORMAL + ch] = a_normal[ch] / n_samples
                        out_aov[row, x, aov.POSITION + ch] = a_point[ch] / n_samples
                    out_aov[row, x, aov.DEPTH] = a_depth / n_samples
                    out_aov[row, x, aov.ALPHA] = a_hits / n_samples
                    out_aov[row, x, aov.OBJECT_ID] = a_object
                    out_aov[row, x, aov.MATERIAL_ID] = a_material

    trace_pixels.__qualname__ = f"trace_pixels_{build_name(materials, lights)}"
    return jit(
        with_globals(
            trace_pixels,
            shade=SHADERS[(materials, lights)],
            **traversals(materials),
        )
    )


KERNELS = {build: path_kernel(*build) for build in BUILDS}
"""The path kernel's four builds, by (materials, lights); ``kernel_for`` picks one for a plan."""


def build_for(plan: int) -> tuple[bool, bool]:
    """The build ``(materials, lights)`` a plan needs: with the material dispatch if it has a
    material effect, surface detail or samples lights with the tree (or has the
    ``flags.MATERIAL_BUILD`` switch), with the point/spot/sun/sky code if it has one of those
    lights."""
    rich = flags.MATERIAL_EFFECTS | flags.SURFACE_DETAIL | flags.LIGHT_TREE | flags.MATERIAL_BUILD
    materials = (plan & rich) != 0
    lights = (plan & (flags.POINT_LIGHTS | flags.SUN | flags.SKY)) != 0
    return materials, lights


def kernel_for(plan: int):
    """The build of the path kernel that a plan needs (``build_for``)."""
    return KERNELS[build_for(plan)]
