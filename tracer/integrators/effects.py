"""The effect plan: which parts of the light transport a scene needs, as kernel flags.

A scene compiles into the set of effects it needs (DESIGN.md, invariant 5); the kernels run only
those. Every rule below removes work that provably adds nothing to the image, so the plan's
image is the all-effects image (statistically, and in practice bit for bit: a skipped step
would only have added zeros, and random numbers are drawn per path vertex at fixed dimensions,
so skipping one never shifts another). ``docs/effects.md`` lists the rules with their reasons.

Users may also switch effects off on purpose (``render.effects``, e.g. ``{"shadows": false}``):
that changes the image, as asked. ``render.effect_plan: false`` enables every effect the user
did not switch off, whatever the scene needs: the reference the plan is checked against.
"""

from dataclasses import dataclass

from tracer.scene import format as fmt
from tracer.shading import bsdf, lights

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

NO_MIS = 1 << 13
"""Not an effect, and never in a plan this module makes: a sampling switch for the accuracy
study (``cli/accuracy.py``), set on an explicit plan. The path tracer then samples lights
without MIS: light samples alone for direct light, and emitters that BSDF-sampled rays hit
count only after delta bounces and for camera rays. The same image in expectation, noisier."""
MATERIAL_BUILD = 1 << 14
"""Not an effect either, and never in a plan this module makes: a kernel switch that runs the
path kernel's build with the material dispatch (``integrator.kernel_for``) even where the plan
has no material effect, so every surface is still Lambertian. The accuracy study times all of
Reiter's stages of a scene in one build, as his renderer switched effects at run time."""

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
}
ALL = sum(EFFECTS.values())
MATERIAL_EFFECTS = SPECULAR | GLOSSY | REFRACTION | ABSORPTION
"""Any of these needs the general BSDF dispatch; without them every surface is Lambertian."""

LIGHT_KIND_EFFECTS = {
    lights.TRIANGLE: AREA_LIGHTS,
    lights.POINT: POINT_LIGHTS,
    lights.SPOT: POINT_LIGHTS,
    lights.SUN: SUN,
    lights.SKY: SKY,
}


@dataclass(frozen=True)
class EffectPlan:
    """The flags a render runs with, and why each needed effect is needed (or not)."""

    flags: int
    reasons: dict[str, str]
    """Effect name -> the rule that decided it."""

    def names(self) -> list[str]:
        """Names of the enabled effects, in ``EFFECTS`` order."""
        return [name for name, bit in EFFECTS.items() if self.flags & bit]

    def light_kinds(self) -> frozenset[int]:
        """The light kinds (``tracer.shading.lights`` constants) the plan keeps."""
        return frozenset(k for k, bit in LIGHT_KIND_EFFECTS.items() if self.flags & bit)

    def to_json(self) -> dict:
        """What render metadata and ``tilerender plan`` show."""
        return {
            "effects": self.names(),
            "skipped": [name for name, bit in EFFECTS.items() if not self.flags & bit],
            "reasons": self.reasons,
        }


def needed_effects(scene, settings: fmt.RenderSettings) -> EffectPlan:
    """The effects ``scene`` (a ``CompiledScene``) needs under ``settings``, each with its rule.

    Rules (docs/effects.md):

    - a light kind is needed iff the scene has a light of that kind with non-zero power;
    - light samples are needed iff some light can be sampled and the integrator samples lights;
    - shadows are needed iff light samples are;
    - emitter hits are needed iff emissive triangles, the sky or a sun disc exist;
    - specular / glossy / refraction / absorption iff a material of that model is used by a
      visible object (absorption: a dielectric with a non-zero absorption coefficient);
    - indirect light is needed iff the path can have more than two vertices, some non-emissive
      material reflects anything, and something emits;
    - textures are needed iff a visible object's material has a texture and the integrator
      reads base colours (all but ``ao``, ``normal`` and ``depth``).
    """
    table = scene.lights
    weight = table.weight
    kinds_present = {int(k) for k, w in zip(table.kind, weight, strict=True) if w > 0.0}
    flags = 0
    reasons: dict[str, str] = {}

    def decide(name: str, needed: bool, why_yes: str, why_no: str) -> None:
        nonlocal flags
        if needed:
            flags |= EFFECTS[name]
        reasons[name] = why_yes if needed else why_no

    decide(
        "area_lights",
        lights.TRIANGLE in kinds_present,
        "emissive triangles",
        "no emissive triangles",
    )
    decide(
        "point_lights",
        bool(kinds_present & {lights.POINT, lights.SPOT}),
        "point or spot lights",
        "no point or spot lights",
    )
    decide("sun", lights.SUN in kinds_present, "a sun", "no sun")
    decide("sky", lights.SKY in kinds_present, "a sky that emits", "the sky is black")
    emitting = bool(kinds_present)
    light_integrator = settings.integrator in ("path", "direct", "whitted", "cost")
    decide(
        "light_samples",
        emitting and light_integrator,
        "lights to sample",
        "no light to sample" if light_integrator else f"{settings.integrator} samples no lights",
    )
    decide(
        "shadows",
        bool(flags & LIGHT_SAMPLES),
        "light samples need shadow rays",
        "no light samples",
    )
    suns_visible = scene.arrays.light_env.shape[0] > 0
    decide(
        "emitter_hits",
        bool(kinds_present & {lights.TRIANGLE, lights.SKY}) or suns_visible,
        "rays can hit emitters (emissive triangles, the sky or a sun disc)",
        "nothing a ray can hit emits (only point, spot or directional lights)",
    )
    used = _used_materials(scene)
    kinds = {int(scene.materials.kind[m]) for m in used}
    params = {m: scene.materials.param[m] for m in used}
    smooth_conductor = any(
        scene.materials.kind[m] == bsdf.CONDUCTOR and p[bsdf.ALPHA] < bsdf.SMOOTH_ALPHA
        for m, p in params.items()
    )
    rough_conductor = any(
        scene.materials.kind[m] == bsdf.CONDUCTOR and p[bsdf.ALPHA] >= bsdf.SMOOTH_ALPHA
        for m, p in params.items()
    )
    decide(
        "specular",
        bsdf.MIRROR in kinds or bsdf.DIELECTRIC in kinds or smooth_conductor,
        "mirrors, dielectrics or smooth conductors",
        "no mirror, dielectric or smooth conductor",
    )
    decide(
        "glossy",
        bsdf.PLASTIC in kinds or rough_conductor,
        "rough conductors or plastics",
        "no rough conductor or plastic",
    )
    decide(
        "refraction",
        bsdf.DIELECTRIC in kinds,
        "dielectrics",
        "no dielectric",
    )
    absorbing = any(
        scene.materials.kind[m] == bsdf.DIELECTRIC and max(p[bsdf.SIGMA : bsdf.SIGMA + 3]) > 0.0
        for m, p in params.items()
    )
    decide("absorption", absorbing, "an absorbing dielectric", "no absorbing dielectric")
    reflects = any(_reflects(scene, m) for m in used)
    deep = settings.max_depth > 2 and settings.integrator in ("path", "cost")
    decide(
        "indirect",
        deep and reflects and emitting,
        "paths longer than two vertices over reflecting surfaces",
        "max_depth <= 2"
        if settings.max_depth <= 2
        else f"the {settings.integrator} integrator has no indirect light"
        if not deep
        else "no surface reflects"
        if not reflects
        else "nothing emits",
    )
    textured = any(scene.textures.material[m] >= 0 for m in used)
    reads_colour = settings.integrator not in ("ao", "normal", "depth")
    decide(
        "textures",
        textured and reads_colour,
        "textured materials",
        "no textured material"
        if not textured
        else f"the {settings.integrator} output reads no base colour",
    )
    return EffectPlan(flags, reasons)


def _used_materials(scene) -> list[int]:
    """Indices of the materials some geometry uses."""
    names = {node.material for node in scene.state.geometry_nodes()}
    return [i for i, name in enumerate(scene.material_names) if name in names]


def _reflects(scene, m: int) -> bool:
    """Whether material ``m`` sends any light on (a non-black reflectance or a dielectric)."""
    kind = int(scene.materials.kind[m])
    if kind in (bsdf.DIELECTRIC, bsdf.CONDUCTOR, bsdf.PLASTIC):
        return True
    return bool(scene.materials.albedo[m].max() > 0.0)


def effect_plan(scene, settings: fmt.RenderSettings) -> EffectPlan:
    """The plan a render runs: the needed effects (or all of them, with ``effect_plan`` false),
    minus those the user switched off."""
    needed = needed_effects(scene, settings)
    flags = needed.flags if settings.effect_plan else ALL
    reasons = dict(needed.reasons)
    if not settings.effect_plan:
        reasons = {name: "effect_plan is false: every effect runs" for name in EFFECTS}
    for name, enabled in settings.effects.items():
        if not enabled:
            flags &= ~EFFECTS[name]
            reasons[name] = "switched off in render.effects"
    if not flags & LIGHT_SAMPLES:
        flags &= ~SHADOWS
    return EffectPlan(flags, reasons)
