"""The effect plan: which parts of the light transport a scene needs, as kernel flags
(``tracer.integrators.flags``).

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

from tracer.integrators.flags import (
    ALL,
    AREA_LIGHTS,
    EFFECTS,
    LIGHT_SAMPLES,
    LIGHT_TREE,
    NORMAL_BENDING,
    NORMAL_MAPS,
    SHADING_NORMALS,
    SHADOW_TERMINATOR,
    SHADOWS,
)
from tracer.integrators.registry import REGISTRY
from tracer.scene import format as fmt
from tracer.shading import bsdf, lights, textures


@dataclass(frozen=True)
class EffectPlan:
    """The flags a render runs with, and why each needed effect is needed (or not)."""

    flags: int
    reasons: dict[str, str]
    """Effect name -> the rule that decided it."""

    def names(self) -> list[str]:
        """Names of the enabled effects, in ``EFFECTS`` order."""
        return [name for name, bit in EFFECTS.items() if self.flags & bit]

    def to_json(self) -> dict:
        """What render metadata and ``tilerender plan`` show."""
        return {
            "effects": self.names(),
            "skipped": [name for name, bit in EFFECTS.items() if not self.flags & bit],
            "reasons": self.reasons,
            "light_sampler": "tree" if self.flags & LIGHT_TREE else "power",
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
      reads base colours (all but ``ao``, ``normal`` and ``depth``);
    - shading normals are needed iff a mesh in the scene has vertex normals and the integrator
      shades with normals (all but ``albedo`` and ``depth``); normal maps iff a used material
      has one and the integrator shades with normals; the shadow terminator's falloff iff
      either is needed and the integrator samples lights, and so is bending them toward the
      viewer;
    - the alpha test is needed iff a used material has ``alpha`` (mask or blend) and the
      integrator's kernels test it (the path kernels).
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
    integrator = REGISTRY[settings.integrator]
    light_integrator = integrator.samples_lights
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
    deep = settings.max_depth > 2 and integrator.indirect
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
    reads_colour = integrator.reads_colour
    decide(
        "textures",
        textured and reads_colour,
        "textured materials",
        "no textured material"
        if not textured
        else f"the {settings.integrator} output reads no base colour",
    )
    smooth = any(rows.shape[0] > 0 for rows in scene.arrays.tri_normal)
    decide(
        "shading_normals",
        smooth and integrator.reads_normals,
        "meshes with vertex normals",
        "no mesh has vertex normals"
        if not smooth
        else f"the {settings.integrator} output reads no normal",
    )
    mapped = any(scene.textures.normal_map[m] >= 0 for m in used)
    decide(
        "normal_maps",
        mapped and integrator.reads_normals,
        "materials with normal maps",
        "no material has a normal map"
        if not mapped
        else f"the {settings.integrator} output reads no normal",
    )
    tilted = bool(flags & (SHADING_NORMALS | NORMAL_MAPS))
    decide(
        "shadow_terminator",
        tilted and integrator.samples_lights,
        "shading normals on surfaces that reflect light",
        "no shading normals" if not tilted else "no reflected light",
    )
    decide(
        "normal_bending",
        tilted and integrator.samples_lights,
        "shading normals the viewer may fall below",
        "no shading normals" if not tilted else "no shaded paths",
    )
    cut_out = any(scene.textures.alpha[m, textures.MODE] != textures.OPAQUE for m in used)
    decide(
        "alpha_test",
        cut_out and integrator.tests_alpha,
        "materials with alpha (mask or blend)",
        "no material has alpha"
        if not cut_out
        else f"the {settings.integrator} output sees every surface opaque",
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


TREE_MIN_TRIANGLES = 64
"""Emissive triangles from which ``render.light_sampler`` ``auto`` picks them with the light tree
(``bench/light_tree.py``, docs/performance.md "Many lights")."""


def light_sampler(scene, settings: fmt.RenderSettings, flags: int) -> tuple[bool, str]:
    """Whether light samples pick emissive triangles with the light tree, and why."""
    if not (flags & LIGHT_SAMPLES and flags & AREA_LIGHTS):
        return False, "no light samples on emissive triangles"
    if settings.light_sampler != "auto":
        return settings.light_sampler == "tree", "set in render.light_sampler"
    count = scene.stats.emissive_triangles
    if count >= TREE_MIN_TRIANGLES:
        return True, f"{count} emissive triangles: the tree gains from {TREE_MIN_TRIANGLES} on"
    return False, f"{count} emissive triangles: by power below {TREE_MIN_TRIANGLES}"


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
    if not flags & (SHADING_NORMALS | NORMAL_MAPS):
        flags &= ~(SHADOW_TERMINATOR | NORMAL_BENDING)
    tree, reasons["light_tree"] = light_sampler(scene, settings, flags)
    return EffectPlan(flags | (LIGHT_TREE if tree else 0), reasons)
