"""The scene format's materials and textures (docs/materials.md); part of
``tracer.scene.format``, through which they are used."""

from typing import Annotated, Literal

from pydantic import Field, Tag, model_validator

from tracer.scene.format_base import (
    FilePath,
    NonNegative,
    Positive,
    Radiance,
    Reflectance,
    Strict,
    Unit,
    type_tag,
)


class Texture(Strict):
    """An image that multiplies a material's base colour, looked up through the mesh's UVs with
    bilinear filtering (docs/materials.md).

    ``file`` is relative to the scene file (PNG, JPEG and the other formats Pillow reads);
    colour images are sRGB-encoded and decoded to linear on load. ``u`` runs left to right and
    ``v`` bottom to top across the image (OBJ's and OpenGL's convention; glTF files are
    converted on load)."""

    file: FilePath = Field(description="Image file, relative to the scene file")
    wrap: Literal["repeat", "clamp"] = Field(
        default="repeat",
        description="Outside [0, 1]: repeat the image (tiling), or clamp to its edge texels",
    )
    scale: tuple[Positive, Positive] = Field(
        default=(1.0, 1.0), description="UVs are multiplied by this before the lookup (tiling)"
    )


class NormalMap(Texture):
    """A tangent-space normal map (glTF's ``normalTexture``): each texel's RGB, read linearly
    (not sRGB), is a unit vector ``2 c - 1`` along the surface's tangent (``+u``), bitangent
    (``+v``, toward the top of the image) and normal; ``strength`` scales its tangential part
    (glTF's ``scale``). docs/materials.md, *Normal maps*."""

    strength: NonNegative = Field(
        default=1.0, description="Scale of the map's tangential components (0: no effect)"
    )


class Alpha(Strict):
    """Base-colour alpha (glTF's ``alphaMode``): where a surface exists. Its alpha is ``value``
    times the alpha channel of ``texture`` (read linearly, bilinear through the mesh's UVs).
    ``mask``: the surface exists where alpha >= ``cutoff`` and rays pass through it elsewhere;
    ``blend``: a ray meets it with probability alpha (docs/materials.md, *Alpha*)."""

    mode: Literal["mask", "blend"] = Field(description="Cut out (mask) or partly there (blend)")
    cutoff: NonNegative = Field(
        default=0.5, description="mask: the surface exists where alpha >= cutoff"
    )
    value: Unit = Field(default=1.0, description="Alpha, or the factor of the texture's alpha")
    texture: Texture | None = Field(
        default=None,
        description="An image whose alpha channel multiplies value (it must have one); the "
        "mesh must have UVs",
    )


class _Opaque(Strict):
    """What every opaque material has: emission (an area light), sidedness, an optional
    base-colour texture and normal map, and optional alpha (cut-outs)."""

    emission: Radiance = Field(
        default=(0.0, 0.0, 0.0), description="Emitted radiance, linear RGB (W sr^-1 m^-2)"
    )
    two_sided: bool = Field(
        default=True,
        description="Reflect and emit on both sides; one-sided surfaces are black from the back "
        "(the back is the side the counter-clockwise winding faces away from)",
    )
    texture: Texture | None = Field(
        default=None,
        description="An image multiplying the base colour (reflectance) through the mesh's "
        "UVs; the mesh must have UVs",
    )
    normal_map: NormalMap | None = Field(
        default=None,
        description="A tangent-space normal map through the mesh's UVs (the mesh must have "
        "UVs); it tilts the shading normal",
    )
    alpha: Alpha | None = Field(
        default=None,
        description="Cut-outs (mask) or partial coverage (blend); not on emitters",
    )

    @model_validator(mode="after")
    def _check_alpha(self) -> "_Opaque":
        if self.alpha is not None and max(self.emission) > 0.0:
            raise ValueError("alpha is not supported on emissive materials")
        return self


class DiffuseMaterial(_Opaque):
    """Lambertian reflector, optionally emissive (an area light)."""

    type: Literal["diffuse"] = "diffuse"
    reflectance: Reflectance = (0.8, 0.8, 0.8)


class MirrorMaterial(_Opaque):
    """Perfect specular reflector: every ray leaves in the mirror direction, scaled by
    ``reflectance`` (no Fresnel term)."""

    type: Literal["mirror"]
    reflectance: Reflectance = (1.0, 1.0, 1.0)


Ior = Annotated[float, Field(gt=0.0, le=10.0, allow_inf_nan=False)]


class DielectricMaterial(Strict):
    """Smooth glass-like boundary: Fresnel reflection and refraction, total internal reflection,
    and Beer-Lambert absorption inside. Needs closed meshes whose triangles face outward (the
    front side is outside); always two-sided, never emissive."""

    type: Literal["dielectric"]
    ior: Ior = Field(default=1.5, description="Index of refraction inside / outside")
    absorption: Radiance = Field(
        default=(0.0, 0.0, 0.0),
        description="Absorption coefficient inside, per unit of scene length (Beer-Lambert)",
    )


Roughness = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
PositiveVec3 = tuple[Positive, Positive, Positive]


class ConductorMaterial(_Opaque):
    """Metal: GGX microfacet reflection with the conductor Fresnel term (visible-normal
    sampling); roughness 0 is a smooth metal. The Fresnel term comes from ``eta`` and ``k``
    (complex index of refraction per channel) or, if they are not given, from ``reflectance``
    (the colour at normal incidence; docs/materials.md gives the mapping)."""

    type: Literal["conductor"]
    reflectance: Reflectance | None = Field(
        default=None, description="Colour at normal incidence (default 0.9 grey)"
    )
    eta: PositiveVec3 | None = Field(default=None, description="Real part of the index")
    k: tuple[NonNegative, NonNegative, NonNegative] | None = Field(
        default=None, description="Imaginary part of the index (extinction)"
    )
    roughness: Roughness = Field(default=0.0, description="GGX alpha = roughness^2")

    @model_validator(mode="after")
    def _check(self) -> "ConductorMaterial":
        if (self.eta is None) != (self.k is None):
            raise ValueError("give eta and k together")
        if self.eta is not None and self.reflectance is not None:
            raise ValueError("give either reflectance or eta and k, not both")
        return self


class PlasticMaterial(_Opaque):
    """Coated diffuse: a Lambertian base under a dielectric coat with a GGX rough surface
    (a specular lobe with the dielectric Fresnel term, and the base's light scaled by the
    coat's transmission; docs/materials.md)."""

    type: Literal["plastic"]
    reflectance: Reflectance = Field(default=(0.5, 0.5, 0.5), description="Base colour")
    ior: Annotated[float, Field(gt=1.0, le=3.0, allow_inf_nan=False)] = Field(
        default=1.5, description="Index of refraction of the coat"
    )
    roughness: Roughness = Field(
        default=0.1, description="GGX alpha = roughness^2 (at least 0.001)"
    )


Material = Annotated[
    Annotated[DiffuseMaterial, Tag("diffuse")]
    | Annotated[MirrorMaterial, Tag("mirror")]
    | Annotated[DielectricMaterial, Tag("dielectric")]
    | Annotated[ConductorMaterial, Tag("conductor")]
    | Annotated[PlasticMaterial, Tag("plastic")],
    type_tag("diffuse", "mirror", "dielectric", "conductor", "plastic"),
]
"""Material kinds, a union on ``type`` (``diffuse`` when it is missing); docs/materials.md."""
MATERIAL_TYPES = (
    DiffuseMaterial,
    MirrorMaterial,
    DielectricMaterial,
    ConductorMaterial,
    PlasticMaterial,
)
