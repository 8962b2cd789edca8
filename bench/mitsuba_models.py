"""How far Mitsuba 3's rough conductor and plastic models are from ours: directional albedos.

For a view direction at angle theta_o from the normal, the directional albedo is the integral of
``f cos`` over the hemisphere. Both models are integrated with the same samples (common random
numbers), drawn from our own sampler, so the ratio Mitsuba / ours is precise even where the
albedo itself is noisy:

- rough conductor: ours (GGX, height-correlated Smith masking) against Mitsuba's
  ``roughconductor`` (GGX, separable masking), same alpha and complex index;
- plastic base (the diffuse part under the coat): ours
  ``R / (1 - Fdr) T(cos_i) T(cos_o) / (pi eta^2)`` with the rough coat's tables
  (docs/materials.md) against the diffuse component of Mitsuba's ``plastic`` (roughness 0) or
  ``roughplastic`` with the same ``R``; and against Mitsuba's as
  ``tracer.crosscheck.mitsuba_export`` writes it, ``R`` scaled by ``rough_plastic_base_scale``
  (which undoes Mitsuba's sum for
  ``Fdr``, the mean of ``2 R(mu) mu`` over 64 equally spaced ``mu``): what remains is the
  masking of the coat's transmittance;
- plastic, whole (coat and base), rough only: ours against Mitsuba's ``roughplastic`` as
  exported.

Writes ``bench/results/mitsuba_models.json``. Needs Mitsuba (``scalar_rgb``, no libLLVM).
"""

import argparse
import math
import sys

import numpy as np
from common import console, machine_info, package_version, print_machine, print_table, write_results

ROUGHNESS = (0.06, 0.14, 0.2, 0.26, 0.35, 0.45, 0.7, 1.0)
PLASTIC_ROUGHNESS = (0.0, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0)
ANGLES = (0.0, 45.0, 70.0, 80.0, 85.0)
METAL = (0.75, 0.75, 0.78)
"""The colour of the veach-mis plates."""
BASE = 0.5
PLASTIC_IOR = 1.5


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Directional albedo ratios Mitsuba / tilerender of the rough conductor and "
        "the plastic.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--samples", type=int, default=20000, help="directions per estimate")
    parser.add_argument("--seed", type=int, default=1, help="random seed")
    args = parser.parse_args(argv)
    if args.samples < 100:
        parser.error("--samples must be at least 100")
    return args


def local_view(theta_deg: float) -> tuple[float, float, float]:
    theta = math.radians(theta_deg)
    return (math.sin(theta), 0.0, math.cos(theta))


def mitsuba_eval(mi, bsdf, wo, wi, component: int | None = None) -> float:
    """Mitsuba's ``f cos`` (first channel) for camera-side ``wo`` and light-side ``wi``."""
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*wo)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    ctx = mi.BSDFContext()
    if component is not None:
        ctx.component = component
    return float(bsdf.eval(ctx, si, mi.Vector3f(*wi))[0])


def conductor_rows(mi, rng, samples: int) -> list[dict]:
    """Albedo of our rough conductor and Mitsuba's / ours, per roughness and view angle."""
    from tracer.scene import format as fmt
    from tracer.shading import bsdf as ours
    from tracer.shading.materials import material_row

    rows = []
    for roughness in ROUGHNESS:
        material = fmt.ConductorMaterial(type="conductor", reflectance=METAL, roughness=roughness)
        kind, albedo, _, _, row = material_row(material)
        albedo = tuple(float(c) for c in albedo)
        param = tuple(float(p) for p in row[: ours.PARAMS])
        theirs = mi.load_dict(
            {
                "type": "roughconductor",
                "distribution": "ggx",
                "alpha": float(param[ours.ALPHA]),
                "eta": {"type": "rgb", "value": list(param[ours.ETA : ours.ETA + 3])},
                "k": {"type": "rgb", "value": list(param[ours.K : ours.K + 3])},
            }
        )
        for angle in ANGLES:
            wo = local_view(angle)
            u = rng.random((samples, 3))
            mine = other = 0.0
            for u0, u1, u2 in u:
                wi, weight, pdf, _ = ours.bsdf_sample(
                    kind, albedo, param, row, (0.0, 0.0, 1.0), wo, True, True, u0, u1, u2
                )
                if pdf <= 0.0:
                    continue
                mine += weight[0]
                other += mitsuba_eval(mi, theirs, wo, wi) / pdf
            rows.append(
                {
                    "roughness": roughness,
                    "theta_o": angle,
                    "albedo_ours": mine / samples,
                    "ratio": other / mine,
                }
            )
    return rows


def plastic_rows(mi, rng, samples: int) -> list[dict]:
    """Albedo of our plastic (its base; the whole BSDF when rough) and Mitsuba's / ours, per
    roughness and view angle."""
    from tracer.crosscheck.mitsuba_conversions import rough_plastic_base_scale
    from tracer.scene import format as fmt
    from tracer.shading import bsdf as ours
    from tracer.shading.materials import PLASTIC_MIN_ALPHA, material_row

    rows = []
    for roughness in PLASTIC_ROUGHNESS:
        material = fmt.PlasticMaterial(
            type="plastic", reflectance=(BASE,) * 3, ior=PLASTIC_IOR, roughness=roughness
        )
        kind, albedo, _, _, row = material_row(material)
        albedo = tuple(float(c) for c in albedo)
        param = tuple(float(p) for p in row[: ours.PARAMS])
        alpha = param[ours.ALPHA]
        smooth = roughness * roughness <= PLASTIC_MIN_ALPHA
        spec = {
            "int_ior": PLASTIC_IOR,
            "ext_ior": 1.0,
            "diffuse_reflectance": {"type": "rgb", "value": [BASE] * 3},
        }
        scale = 1.0  # the export's factor on diffuse_reflectance (rough plastic only)
        if smooth:
            theirs = mi.load_dict({"type": "plastic", **spec})
        else:
            rough = {"type": "roughplastic", "distribution": "ggx", "alpha": alpha, **spec}
            theirs = mi.load_dict(rough)
            scale = rough_plastic_base_scale(alpha, PLASTIC_IOR)
            rough["diffuse_reflectance"] = {"type": "rgb", "value": [BASE * scale] * 3}
            exported = mi.load_dict(rough)
        base = BASE / (math.pi * PLASTIC_IOR**2)
        for angle in ANGLES:
            wo = local_view(angle)
            t_o = ours.coat_transmittance(param, row, wo[2])
            u = rng.random((samples, 3))
            mine = other = 0.0
            for _, u1, u2 in u:  # cosine-weighted directions: f cos / pdf = pi f
                r, phi = math.sqrt(u1), 2.0 * math.pi * u2
                wi = (r * math.cos(phi), r * math.sin(phi), math.sqrt(max(0.0, 1.0 - u1)))
                pdf = wi[2] / math.pi
                t_i = ours.coat_transmittance(param, row, wi[2])
                mine += base * t_i * t_o / (1.0 - param[ours.FDR_INT]) * math.pi
                other += mitsuba_eval(mi, theirs, wo, wi, component=1) / pdf
            result = {
                "roughness": roughness,
                "theta_o": angle,
                "albedo_ours": mine / samples,
                "ratio": other / mine,
                "ratio_exported": other * scale / mine,  # Mitsuba's base is linear in R
            }
            if not smooth:
                whole_mine = whole_other = 0.0
                for u0, u1, u2 in u:
                    wi, weight, pdf, _ = ours.bsdf_sample(
                        kind, albedo, param, row, (0.0, 0.0, 1.0), wo, True, True, u0, u1, u2
                    )
                    if pdf <= 0.0:
                        continue
                    whole_mine += weight[0]
                    whole_other += mitsuba_eval(mi, exported, wo, wi) / pdf
                result["albedo_whole_ours"] = whole_mine / samples
                result["ratio_whole"] = whole_other / whole_mine
            rows.append(result)
    return rows


def table(
    title: str, rows: list[dict], caption: str, ratio: str = "ratio", albedo: str = "albedo_ours"
) -> None:
    by_roughness: dict[float, dict[float, dict]] = {}
    for row in rows:
        if ratio in row:
            by_roughness.setdefault(row["roughness"], {})[row["theta_o"]] = row
    print_table(
        title,
        ["roughness", *(f"{a:g} deg" for a in ANGLES)],
        [
            [f"{r:g}", *(f"{v[a][ratio]:.4f} ({v[a][albedo]:.3f})" for a in ANGLES)]
            for r, v in by_roughness.items()
        ],
        caption=caption,
    )


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    machine = machine_info()
    print_machine(machine)
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    rng = np.random.default_rng(args.seed)
    with console.status("rough conductor"):
        conductor = conductor_rows(mi, rng, args.samples)
    with console.status("plastic base"):
        plastic = plastic_rows(mi, rng, args.samples)
    table(
        f"Rough conductor (colour {METAL}): albedo ratio Mitsuba / ours (our albedo)",
        conductor,
        "view angle theta_o from the normal; roughness is ours (alpha = roughness^2)",
    )
    table(
        f"Plastic base (R = {BASE}, ior {PLASTIC_IOR}): ratio Mitsuba / ours (our albedo)",
        plastic,
        "roughness 0: Mitsuba's plastic; otherwise roughplastic with alpha = roughness^2",
    )
    table(
        "Plastic base as exported: ratio Mitsuba / ours",
        plastic,
        "rough: diffuse_reflectance times (1 - Fdr_mitsuba) / (1 - Fdr_ours), which undoes "
        "Mitsuba's sum for the internal reflectance; what remains is masking",
        ratio="ratio_exported",
    )
    table(
        "Rough plastic as exported, whole BSDF (coat and base): ratio Mitsuba / ours (our albedo)",
        plastic,
        "our sampler's directions; Mitsuba's roughplastic evaluated with all components",
        ratio="ratio_whole",
        albedo="albedo_whole_ours",
    )
    machine["mitsuba"] = package_version("mitsuba")
    write_results(
        "mitsuba_models",
        {"options": vars(args), "conductor": conductor, "plastic": plastic},
        machine,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
