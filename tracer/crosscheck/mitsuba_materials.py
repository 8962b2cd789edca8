"""The Mitsuba export's materials: each of ours as a Mitsuba BSDF (textures as bitmaps)."""

import hashlib
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from tracer.crosscheck.mitsuba_base import (
    UnsupportedFeature,
    child,
    rgb,
    scalar,
)
from tracer.crosscheck.mitsuba_conversions import mask_opacity, rough_plastic_base_scale
from tracer.io.images import write_image
from tracer.scene import format as fmt
from tracer.scene.model import SceneState, WorldMesh
from tracer.shading.bsdf import ETA, SMOOTH_ALPHA, K
from tracer.shading.materials import (
    PLASTIC_MIN_ALPHA,
    material_row,
    roughness_to_alpha,
)
from tracer.shading.textures import alpha_image_name, linear_texels, srgb_to_linear


class MaterialsWriter:
    """The materials part of the export's writer (``mitsuba_export``): ``write_materials``."""

    state: SceneState
    out: Path
    meshes: list[WorldMesh]
    delta_lights: bool

    def write_materials(self, root: ET.Element) -> dict[str, str]:
        ids = {}
        for i, name in enumerate(sorted({m.material for m in self.meshes})):
            ids[name] = f"material-{i}"
            material = self.state.materials[name]
            bsdf = self._bsdf(name, material)
            if getattr(material, "normal_map", None) is not None:
                bsdf = self._normal_mapped(bsdf, material.normal_map)
            if getattr(material, "two_sided", False):
                wrapper = ET.Element("bsdf", type="twosided")
                wrapper.append(bsdf)
                bsdf = wrapper
            if getattr(material, "alpha", None) is not None:
                bsdf = self._masked(name, bsdf, material.alpha)
            bsdf.set("id", ids[name])
            root.append(bsdf)
        return ids

    def _colour(
        self, parent: ET.Element, name: str, m: fmt.Material, colour, scale: float = 1.0
    ) -> None:
        """The base colour ``colour`` of ``m`` times ``scale`` as parameter ``name``: an RGB
        value, or with a texture a bitmap of the texture's linear texels times both."""
        texture = getattr(m, "texture", None)
        if texture is None:
            rgb(parent, name, np.asarray(colour, dtype=np.float64) * scale)
            return
        # The kernels multiply the float32 colour by the float32 linear texel.
        linear = srgb_to_linear(self.state.textures[texture.file]).astype(np.float64)
        tint = np.asarray(colour, dtype=np.float32).astype(np.float64)
        texels = (linear * tint * scale).astype(np.float32)
        digest = hashlib.sha256(np.ascontiguousarray(texels).tobytes())
        digest.update(repr(texels.shape).encode())
        relative = f"textures/texture-{digest.hexdigest()[:16]}.exr"
        if not (self.out / relative).exists():
            write_image(self.out / relative, texels)
        element = child(parent, "texture", type="bitmap", name=name)
        child(element, "string", name="filename", value=relative)
        child(element, "boolean", name="raw", value="true")
        child(element, "string", name="filter_type", value="bilinear")
        child(element, "string", name="wrap_mode", value=texture.wrap)

    def _normal_mapped(self, bsdf: ET.Element, normal_map: fmt.NormalMap) -> ET.Element:
        """``bsdf`` under Mitsuba's ``normalmap``: the map's linear texels with its strength
        baked in (Mitsuba normalises ``2 c - 1`` as we do, and has no strength), as a raw
        float bitmap. Mitsuba's frame is ours: ``dp/du`` made orthogonal to the normal, and
        their cross product. Its two fixes (on by default since 3.7.1) are switched off, so
        that it is the twin of ours with both effects off (docs/mitsuba.md): flipping a
        normal the viewer is below (ours: bending, or nothing scattered) and Estevez et al.'s
        shadowing term (ours: Chiang et al.'s terminator falloff)."""
        texels = self.state.textures[normal_map.file].astype(np.float64) / 255.0
        vector = (2.0 * texels - 1.0) * [normal_map.strength, normal_map.strength, 1.0]
        encoded = ((vector + 1.0) / 2.0).astype(np.float32)
        digest = hashlib.sha256(np.ascontiguousarray(encoded).tobytes())
        digest.update(repr(encoded.shape).encode())
        relative = f"textures/normals-{digest.hexdigest()[:16]}.exr"
        if not (self.out / relative).exists():
            write_image(self.out / relative, encoded)
        wrapper = ET.Element("bsdf", type="normalmap")
        element = child(wrapper, "texture", type="bitmap", name="normalmap")
        child(element, "string", name="filename", value=relative)
        child(element, "boolean", name="raw", value="true")
        child(element, "string", name="filter_type", value="bilinear")
        child(element, "string", name="wrap_mode", value=normal_map.wrap)
        child(wrapper, "boolean", name="flip_invalid_normals", value="false")
        child(wrapper, "boolean", name="use_shadowing_function", value="false")
        wrapper.append(bsdf)
        return wrapper

    def _masked(self, name: str, bsdf: ET.Element, alpha: fmt.Alpha) -> ET.Element:
        """``bsdf`` under Mitsuba's ``mask``, whose opacity is the surface's chance of being
        there: for ``blend`` our alpha (value times the alpha texels, bilinear), for ``mask``
        our bilinear alpha thresholded at the cutoff on a grid ``upsampled`` times finer than
        the texels, looked up nearest (``mitsuba_conversions.mask_opacity``)."""
        wrapper = ET.Element("bsdf", type="mask")
        if alpha.texture is None:
            covered = alpha.value >= alpha.cutoff if alpha.mode == "mask" else alpha.value
            scalar(wrapper, "opacity", float(covered))
            wrapper.append(bsdf)
            return wrapper
        image = self.state.textures[alpha_image_name(alpha.texture.file)]
        texels = linear_texels(image)[:, :, 0].astype(np.float64) * alpha.value  # the kernels'

        filter_type = "bilinear"
        if alpha.mode == "mask":
            texels, factor = mask_opacity(texels, alpha.texture.wrap, alpha.cutoff)
            filter_type = "nearest"
            self.note(
                f"alpha mask {name!r}",
                "proxy",
                f"the cut-out is our bilinear alpha thresholded at the cutoff on {factor} x "
                f"{factor} points per texel, looked up nearest: exact where the cut follows "
                "texel edges (binary alpha at cutoff 0.5), else within a sub-texel",
            )
        grey = np.repeat(texels[:, :, None], 3, axis=2).astype(np.float32)
        digest = hashlib.sha256(np.ascontiguousarray(grey).tobytes())
        digest.update(repr(grey.shape).encode())
        relative = f"textures/opacity-{digest.hexdigest()[:16]}.exr"
        if not (self.out / relative).exists():
            write_image(self.out / relative, grey)
        element = child(wrapper, "texture", type="bitmap", name="opacity")
        child(element, "string", name="filename", value=relative)
        child(element, "boolean", name="raw", value="true")
        child(element, "string", name="filter_type", value=filter_type)
        child(element, "string", name="wrap_mode", value=alpha.texture.wrap)
        wrapper.append(bsdf)
        return wrapper

    def _bsdf(self, name: str, m: fmt.Material) -> ET.Element:
        if isinstance(m, fmt.DiffuseMaterial):
            bsdf = ET.Element("bsdf", type="diffuse")
            self._colour(bsdf, "reflectance", m, m.reflectance)
            return bsdf
        if isinstance(m, fmt.MirrorMaterial):
            bsdf = ET.Element("bsdf", type="conductor")
            child(bsdf, "string", name="material", value="none")
            self._colour(bsdf, "specular_reflectance", m, m.reflectance)
            return bsdf
        if isinstance(m, fmt.DielectricMaterial):
            bsdf = ET.Element("bsdf", type="dielectric")
            scalar(bsdf, "int_ior", m.ior)
            scalar(bsdf, "ext_ior", 1.0)
            return bsdf
        if isinstance(m, fmt.ConductorMaterial):
            return self._conductor(name, m)
        if isinstance(m, fmt.PlasticMaterial):
            return self._plastic(name, m)
        raise UnsupportedFeature(f"material {name!r} of type {m.type!r}", "no Mitsuba twin")

    def _conductor(self, name: str, m: fmt.ConductorMaterial) -> ET.Element:
        param = material_row(m)[4]  # eta and k: given, or Gulbrandsen's from the colour
        alpha = roughness_to_alpha(m.roughness)
        if alpha < SMOOTH_ALPHA:
            bsdf = ET.Element("bsdf", type="conductor")
        else:
            bsdf = ET.Element("bsdf", type="roughconductor")
            child(bsdf, "string", name="distribution", value="ggx")
            scalar(bsdf, "alpha", alpha)
            self.note(
                f"rough conductor {name!r}",
                "model",
                "Mitsuba's Smith masking-shadowing is the separable G1(wo) G1(wi), ours the "
                "height-correlated form: within 0.03% below roughness 0.15; at 85 degrees from "
                "the normal Mitsuba's albedo is 0.8% lower at roughness 0.26, 4% at 0.45 "
                "(docs/mitsuba.md)",
            )
        rgb(bsdf, "eta", param[ETA : ETA + 3])
        rgb(bsdf, "k", param[K : K + 3])
        if m.texture is not None:  # a tint on the Fresnel term
            self._colour(bsdf, "specular_reflectance", m, (1.0, 1.0, 1.0))
        return bsdf

    def _plastic(self, name: str, m: fmt.PlasticMaterial) -> ET.Element:
        alpha = roughness_to_alpha(m.roughness)
        scale = 1.0
        if alpha <= PLASTIC_MIN_ALPHA:
            bsdf = ET.Element("bsdf", type="plastic")
            if self.delta_lights:
                self.note(
                    f"smooth plastic {name!r} under delta lights",
                    "model",
                    f"our coat keeps a GGX alpha of {PLASTIC_MIN_ALPHA:g}, Mitsuba's smooth "
                    "plastic is a perfect mirror: ours shows point, spot and radius-0 sun "
                    "lights as pinpoint highlights and their caustics off the coat, which "
                    "Mitsuba's path tracer cannot (under area lights, sun discs and skies "
                    "the two agree)",
                )
        else:
            bsdf = ET.Element("bsdf", type="roughplastic")
            child(bsdf, "string", name="distribution", value="ggx")
            scalar(bsdf, "alpha", alpha)
            scale = rough_plastic_base_scale(alpha, float(m.ior))
            self.note(
                f"rough plastic {name!r}",
                "model",
                "Mitsuba's roughplastic is our model with separable masking in its coat tables "
                "and its internal reflectance summed over 64 cosines (below the integral); "
                f"diffuse_reflectance is scaled by {scale:.5f} to undo the latter; the masking "
                "remains: up to roughness 0.3 the bases agree within 0.1% (0.3% at 85 degrees "
                "from the normal), from 0.5 Mitsuba's coat passes and reflects less light, "
                "several percent off the normal (docs/mitsuba.md)",
            )
        scalar(bsdf, "int_ior", m.ior)
        scalar(bsdf, "ext_ior", 1.0)
        self._colour(bsdf, "diffuse_reflectance", m, m.reflectance, scale)
        child(bsdf, "boolean", name="nonlinear", value="false")
        return bsdf
