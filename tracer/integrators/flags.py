"""The effects of light transport the kernels can run, as flag bits of an effect plan.

Each bit guards a step of the kernels (``tracer.integrators.path``, ``tracer.integrators.surface``);
the effect plan (``tracer.integrators.effects``) decides which of them a scene needs.
"""

from tracer.shading import lights

AREA_LIGHTS = 1 << 0
"""Emissive triangles: their emission where rays hit them, and light samples on them."""
POINT_LIGHTS = 1 << 1
"""Point and spot lights (light samples only: rays never hit them)."""
SUN = 1 << 2
"""Sun lights: light samples, and the disc where rays that escape see it."""
SKY = 1 << 3
"""The sky (constant, gradient or an environment map): its radiance where rays escape, and light
samples on it."""
SHADOWS = 1 << 4
"""Shadow rays for light samples (off: lights shine through everything)."""
INDIRECT = 1 << 5
"""Bounces past direct light (off: paths stop after two vertices, like ``direct``)."""
REFRACTION = 1 << 6
"""Transmission through dielectrics (off: they only reflect, with their Fresnel weight)."""
ABSORPTION = 1 << 7
"""Beer-Lambert absorption inside dielectrics."""
SPECULAR = 1 << 8
"""Delta lobes: mirrors, smooth conductors, dielectrics."""
GLOSSY = 1 << 9
"""GGX lobes: rough conductors and plastics."""
EMITTER_HITS = 1 << 10
"""Something a BSDF-sampled ray can hit emits (emissive triangles, the sky, a sun disc): the
last path vertex traces its continuation ray only to find such emission."""
LIGHT_SAMPLES = 1 << 11
"""Next-event estimation at all."""
TEXTURES = 1 << 12
"""Base-colour texture lookups where rays hit textured materials."""
SHADING_NORMALS = 1 << 16
"""Interpolated vertex normals where rays hit meshes that have them (off: every surface shades
with its geometric normal, faceted)."""
NORMAL_MAPS = 1 << 18
"""Tangent-space normal maps where rays hit materials that have them
(``tracer.shading.normal_maps``)."""
NORMAL_BENDING = 1 << 19
"""Turning a shading normal toward the viewer where the viewer is below it
(``tracer.shading.shading_normals.bent_normal``); off: such points are black, as Mitsuba and
pbrt shade them."""
SHADOW_TERMINATOR = 1 << 17
"""Chiang et al.'s falloff of light reflected where shading and geometric normals disagree
(``tracer.shading.shading_normals.terminator``); off: shading normals without it, as Mitsuba and
pbrt shade."""
ALPHA_TEST = 1 << 21
"""Base-colour alpha where closest-hit and shadow rays meet materials with ``alpha``: a
``mask`` surface does not exist where its alpha is below the cutoff, a ``blend`` one exists with
probability alpha (``tracer.shading.alpha``); off: every surface is opaque."""

NO_MIS = 1 << 13
"""Not an effect, and never in a plan ``tracer.integrators.effects`` makes: a sampling switch for
the accuracy study (``cli/accuracy.py``), set on an explicit plan. The path tracer then samples
lights without MIS: light samples alone for direct light, and emitters that BSDF-sampled rays hit
count only after delta bounces and for camera rays. The same image in expectation, noisier."""
MATERIAL_BUILD = 1 << 14
"""Not an effect either, and never in a plan ``tracer.integrators.effects`` makes: a kernel switch
that runs the path kernel's build with the material dispatch
(``tracer.integrators.path.kernel_for``) even where the plan has no material effect, so every
surface is still Lambertian. The accuracy study times all of Reiter's stages of a scene in one
build, as his renderer switched effects at run time."""
AOVS = 1 << 15
"""Not an effect: an output switch set by ``tracer.render`` when a render asks for AOVs
(``render.aovs``). The path kernel then records ``tracer.integrators.aov``'s outputs from its
paths; the beauty's bits are the same with it or without it."""
LIGHT_TREE = 1 << 20
"""Not an effect (the image is the same in expectation): a sampling switch the plan sets when
a scene has enough emissive triangles to gain from it (``tracer.integrators.effects``). Next-event
estimation then picks emissive triangles with the light tree (``tracer.shading.light_tree``)
from their share of the power, and emitters that BSDF-sampled rays hit are weighted with the
tree's probability as seen from the previous vertex."""

EFFECTS = {
    "area_lights": AREA_LIGHTS,
    "point_lights": POINT_LIGHTS,
    "sun": SUN,
    "sky": SKY,
    "shadows": SHADOWS,
    "indirect": INDIRECT,
    "refraction": REFRACTION,
    "absorption": ABSORPTION,
    "specular": SPECULAR,
    "glossy": GLOSSY,
    "emitter_hits": EMITTER_HITS,
    "light_samples": LIGHT_SAMPLES,
    "textures": TEXTURES,
    "shading_normals": SHADING_NORMALS,
    "normal_maps": NORMAL_MAPS,
    "shadow_terminator": SHADOW_TERMINATOR,
    "normal_bending": NORMAL_BENDING,
    "alpha_test": ALPHA_TEST,
}
ALL = sum(EFFECTS.values())
MATERIAL_EFFECTS = SPECULAR | GLOSSY | REFRACTION | ABSORPTION
"""Any of these needs the general BSDF dispatch; without them every surface is Lambertian."""
SURFACE_DETAIL = TEXTURES | SHADING_NORMALS | NORMAL_MAPS | ALPHA_TEST
"""Any of these needs the kernels' build with the material dispatch too, which alone compiles the
look-ups of textures, vertex normals and normal maps, and the alpha test in its traversals
(``tracer.integrators.path.build_for``)."""

LIGHT_KIND_EFFECTS = {
    lights.TRIANGLE: AREA_LIGHTS,
    lights.POINT: POINT_LIGHTS,
    lights.SPOT: POINT_LIGHTS,
    lights.SUN: SUN,
    lights.SKY: SKY,
}


def light_kinds(flags: int) -> frozenset[int]:
    """The light kinds (``tracer.shading.lights`` constants) a plan's flags keep."""
    return frozenset(k for k, bit in LIGHT_KIND_EFFECTS.items() if flags & bit)
