"""The stream (wavefront) path tracer: the path kernel's paths, traced a stage at a time over
a stream of paths in flight (the Ray Accelerator's ray streams, ``docs/performance.md``).

Per thread, ``STREAM_SIZE`` paths live in structure-of-arrays buffers. Each round runs the
stages over the whole stream: regenerate (camera rays of new samples fill the free slots),
trace (every path's closest hit), shade (``tracer.integrators.vertex.shade`` at every hit, in
runs of one material: emission, the light sample's shadow ray and the continuation ray),
shadows (every pending shadow ray, as a stream of its own) and compact (finished paths leave
the stream, their radiance kept per sample). A pixel's samples are summed in sample order once
all of them have finished.

Each path runs the single-ray kernel's arithmetic in the same order (the same ``shade``, the
same traversals, the shadow ray resolved before the path's next vertex), so the images are
bit-identical to ``tracer.integrators.path``'s, however the frame is split.
"""

import numpy as np

from tracer.compiled.arrays import borrow_scene
from tracer.geometry.alpha_traversal import traversals
from tracer.geometry.scene_intersect import material_of, scene_closest, scene_occluded
from tracer.integrators import flags
from tracer.integrators.path import PIXEL_BLOCK, build_for
from tracer.integrators.vertex import BUILDS, SHADERS, build_name, camera_path
from tracer.kernel.borrow import borrowed
from tracer.kernel.jit import jit, jit_inline, with_globals
from tracer.maths.rng import pixel_key, sample_key
from tracer.shading.camera import camera_sample_ray

STREAM_SIZE = 2048
"""Paths in flight per thread."""
BATCH_SAMPLES = 16384
"""Samples a thread takes on at a time (whole pixel blocks, at least one): their radiance is
kept until the batch's last path finishes."""


@jit_inline
def _load_state(path_f, path_i, q):
    """Path ``q``'s state from the stream's float and integer columns."""
    L = (path_f[q, 6], path_f[q, 7], path_f[q, 8])
    beta = (path_f[q, 9], path_f[q, 10], path_f[q, 11])
    prev_p = (path_f[q, 14], path_f[q, 15], path_f[q, 16])
    prev_n = (path_f[q, 17], path_f[q, 18], path_f[q, 19])
    return L, beta, path_f[q, 12], path_f[q, 13], path_i[q, 2] != 0, path_i[q, 3], prev_p, prev_n


@jit_inline
def _store_path(path_f, path_i, q, o, d, state):
    """Store the next ray and state of path ``q``."""
    L, beta, eta_scale, p_bsdf_prev, delta_prev, depth, prev_p, prev_n = state
    for a in range(3):
        path_f[q, a] = o[a]
        path_f[q, 3 + a] = d[a]
        path_f[q, 6 + a] = L[a]
        path_f[q, 9 + a] = beta[a]
        path_f[q, 14 + a] = prev_p[a]
        path_f[q, 17 + a] = prev_n[a]
    path_f[q, 12] = eta_scale
    path_f[q, 13] = p_bsdf_prev
    path_i[q, 2] = 1 if delta_prev else 0
    path_i[q, 3] = depth


@jit_inline
def _material_runs(s, hit_i, n, order, counts):
    """``order[:n]``: the stream's paths sorted by what shades them (misses first, then by
    material, stable), by counting sort."""
    counts[:] = 0
    for q in range(n):
        k = hit_i[q, 0]
        counts[0 if k < 0 else material_of(s, k, hit_i[q, 1]) + 1] += 1
    total = 0
    for m in range(counts.shape[0]):
        c = counts[m]
        counts[m] = total
        total += c
    for q in range(n):
        k = hit_i[q, 0]
        m = 0 if k < 0 else material_of(s, k, hit_i[q, 1]) + 1
        order[counts[m]] = q
        counts[m] += 1


def stream_kernel(materials: bool, lights: bool):
    """The stream kernel for a build of ``shade`` (as ``tracer.integrators.path.path_kernel``);
    the same arguments as the path kernel's."""

    def trace_stream(
        scene, camera, width, height, p0, p1, sample_start, spp, counts, max_depth, rr_depth,
        seed, frame, shadow_t_max, mode, plan, first, stride, stack_node, stack_t, out_rgb,
        out_cost, out_rays, out_aov,
    ):  # fmt: skip
        """Render pixel blocks ``first, first + stride, ...`` of the pixel run [p0, p1) into the
        outputs, as ``tracer.integrators.path``'s kernel does; it writes no AOVs (``out_aov``
        is untouched: ``tracer.integrators.kernel_choice`` runs the single-ray kernel for
        renders that ask for them)."""
        s = borrow_scene(scene)
        camera = borrowed(camera)
        stack_node = borrowed(stack_node)
        stack_t = borrowed(stack_t)
        y_first = p0 // width
        n_blocks = (p1 - p0 + PIXEL_BLOCK - 1) // PIXEL_BLOCK
        batch_blocks = max(1, BATCH_SAMPLES // (PIXEL_BLOCK * spp))
        cap = STREAM_SIZE
        # The stream: per path its ray (o, d), L, beta, eta_scale, p_bsdf_prev, prev_p, prev_n
        # (floats) and its sample, pixel, delta_prev, depth (integers), its key, its hit and its
        # shadow ray.
        path_f = np.empty((cap, 20))
        path_i = np.empty((cap, 4), np.int64)
        path_key = np.empty(cap, np.uint64)
        hit_f = np.empty((cap, 4))
        hit_i = np.empty((cap, 2), np.int64)
        shadow_f = np.empty((cap, 10))
        shadow_on = np.zeros(cap, np.bool_)
        going = np.zeros(cap, np.bool_)
        order = np.empty(cap, np.int64)
        material_counts = np.empty(s.mat_albedo.shape[0] + 1, np.int64)
        pixels = np.empty(batch_blocks * PIXEL_BLOCK, np.int64)
        sample_L = np.empty((batch_blocks * PIXEL_BLOCK * spp, 3))
        pixel_cost = np.empty(batch_blocks * PIXEL_BLOCK, np.int64)
        pixel_rays = np.empty(batch_blocks * PIXEL_BLOCK, np.int64)
        pixel_n = np.empty(batch_blocks * PIXEL_BLOCK, np.int64)
        for batch in range(first, n_blocks, stride * batch_blocks):
            n_pixels = 0
            for block in range(batch, min(n_blocks, batch + stride * batch_blocks), stride):
                start = p0 + block * PIXEL_BLOCK
                for i in range(start, min(p1, start + PIXEL_BLOCK)):
                    pixels[n_pixels] = i
                    pixel_n[n_pixels] = spp if counts.shape[0] == 0 else counts[i]
                    n_pixels += 1
            pixel_cost[:n_pixels] = 0
            pixel_rays[:n_pixels] = 0
            n_samples = n_pixels * spp
            next_sample = 0
            n = 0
            while True:
                # Regenerate: new samples' camera rays fill the free slots (pixel lp's
                # samples have the slots [lp * spp, lp * spp + pixel_n[lp])).
                while n < cap and next_sample < n_samples:
                    lp = next_sample // spp
                    if next_sample - lp * spp >= pixel_n[lp]:
                        next_sample = (lp + 1) * spp
                        continue
                    i = pixels[lp]
                    y = i // width
                    key = sample_key(pixel_key(seed, frame, i), sample_start + next_sample % spp)
                    o, d = camera_sample_ray(camera, width, height, i - y * width, y, key)
                    _store_path(path_f, path_i, n, o, d, camera_path())
                    path_i[n, 0] = next_sample
                    path_i[n, 1] = lp
                    path_key[n] = key
                    n += 1
                    next_sample += 1
                if n == 0:
                    break
                # Trace: every path's closest hit.
                for q in range(n):
                    o = (path_f[q, 0], path_f[q, 1], path_f[q, 2])
                    d = (path_f[q, 3], path_f[q, 4], path_f[q, 5])
                    k, j, t, b0, b1, b2, c = scene_closest(s, o, d, np.inf, stack_node, stack_t)
                    hit_i[q, 0] = k
                    hit_i[q, 1] = j
                    hit_f[q, 0] = t
                    hit_f[q, 1] = b0
                    hit_f[q, 2] = b1
                    hit_f[q, 3] = b2
                    lp = path_i[q, 1]
                    pixel_cost[lp] += c
                    pixel_rays[lp] += 1
                # Shade, in runs of one material.
                _material_runs(s, hit_i, n, order, material_counts)
                for r in range(n):
                    q = order[r]
                    d = (path_f[q, 3], path_f[q, 4], path_f[q, 5])
                    go_on, state, o, d, shadow, s_o, s_d, s_t_max, Ld, _ = shade(  # noqa: F821 (with_globals binds it)
                        s, path_key[q], d, hit_i[q, 0], hit_i[q, 1], hit_f[q, 0], hit_f[q, 1],
                        hit_f[q, 2], hit_f[q, 3], _load_state(path_f, path_i, q), mode, plan,
                        max_depth, rr_depth, shadow_t_max, False,
                    )  # fmt: skip
                    _store_path(path_f, path_i, q, o, d, state)
                    going[q] = go_on
                    shadow_on[q] = shadow
                    if shadow:
                        for a in range(3):
                            shadow_f[q, a] = s_o[a]
                            shadow_f[q, 3 + a] = s_d[a]
                            shadow_f[q, 7 + a] = Ld[a]
                        shadow_f[q, 6] = s_t_max
                # Shadows: the light samples' rays, and their radiance where unblocked.
                for q in range(n):
                    if not shadow_on[q]:
                        continue
                    blocked = False
                    if plan & flags.SHADOWS:
                        s_o = (shadow_f[q, 0], shadow_f[q, 1], shadow_f[q, 2])
                        s_d = (shadow_f[q, 3], shadow_f[q, 4], shadow_f[q, 5])
                        blocked, c = scene_occluded(s, s_o, s_d, shadow_f[q, 6], stack_node)
                        lp = path_i[q, 1]
                        pixel_cost[lp] += c
                        pixel_rays[lp] += 1
                    if not blocked:
                        for a in range(3):
                            path_f[q, 6 + a] = path_f[q, 6 + a] + shadow_f[q, 7 + a]
                # Compact: finished paths leave their radiance and the stream.
                m = 0
                for q in range(n):
                    if not going[q]:
                        for a in range(3):
                            sample_L[path_i[q, 0], a] = path_f[q, 6 + a]
                        continue
                    if m != q:
                        path_f[m] = path_f[q]
                        path_i[m] = path_i[q]
                        path_key[m] = path_key[q]
                    m += 1
                n = m
            # Each pixel's samples, summed in sample order.
            for lp in range(n_pixels):
                i = pixels[lp]
                y = i // width
                x = i - y * width
                row = y - y_first
                acc = (0.0, 0.0, 0.0)
                for k in range(lp * spp, lp * spp + pixel_n[lp]):
                    acc = (acc[0] + sample_L[k, 0], acc[1] + sample_L[k, 1],
                           acc[2] + sample_L[k, 2])  # fmt: skip
                out_rgb[row, x, 0] = acc[0] / pixel_n[lp]
                out_rgb[row, x, 1] = acc[1] / pixel_n[lp]
                out_rgb[row, x, 2] = acc[2] / pixel_n[lp]
                out_cost[row, x] = pixel_cost[lp]
                out_rays[row, x] = pixel_rays[lp]

    trace_stream.__qualname__ = f"trace_stream_{build_name(materials, lights)}"
    return jit(
        with_globals(trace_stream, shade=SHADERS[(materials, lights)], **traversals(materials))
    )


KERNELS = {build: stream_kernel(*build) for build in BUILDS}
"""The stream kernel's four builds, by (materials, lights), as ``tracer.integrators.path``'s."""


def kernel_for(plan: int):
    """The build of the stream kernel that a plan needs (the path kernel's rule)."""
    return KERNELS[build_for(plan)]
