"""The JSON scene description (format ``tilerender/1``), as pydantic models.

The JSON Schema exported from :class:`SceneFile` lives in ``docs/scene-schema.json``; the user
guide is ``docs/scene-format.md``. Every model forbids unknown keys and non-finite numbers, so a
typo or a NaN is an error at load time rather than a surprise in the image.
"""

from typing import Annotated, Literal

import numpy as np
from pydantic import Discriminator, Field, Tag, field_validator, model_validator

from tracer import config
from tracer.integrators.names import (
    ADAPTIVE,
    AOV_INTEGRATORS,
    DENOISE,
    DENOISE_PREFILTER,
    INTEGRATORS,
    KERNELS,
    LIGHT_SAMPLERS,
)
from tracer.maths import portable
from tracer.scene.format_animation import (
    MAX_FRAMES,
    AnimationSettings,
    CameraKeyframe,
    CameraTrack,
    ObjectKeyframe,
    ObjectTrack,
    Time,
    Vec4,
)
from tracer.scene.format_base import (
    MAX_NAME,
    MAX_PATH,
    FilePath,
    Finite,
    Name,
    NonNegative,
    Positive,
    Radiance,
    Reflectance,
    Strict,
    Transform,
    Unit,
    Vec3,
    Vec4Row,
)
from tracer.scene.format_lights import (
    ConstantSky,
    Direction,
    EnvironmentSky,
    GradientSky,
    Light,
    PointLight,
    Sky,
    SpotLight,
    SunLight,
)
from tracer.scene.format_materials import (
    MATERIAL_TYPES,
    Alpha,
    ConductorMaterial,
    DielectricMaterial,
    DiffuseMaterial,
    Ior,
    Material,
    MirrorMaterial,
    NormalMap,
    PlasticMaterial,
    PositiveVec3,
    Roughness,
    Texture,
)

__all__ = [
    "FORMAT",
    "INTEGRATORS",
    "MATERIAL_TYPES",
    "MAX_FRAMES",
    "MAX_NAME",
    "MAX_PATH",
    "Alpha",
    "AnimationSettings",
    "Box",
    "Camera",
    "CameraKeyframe",
    "CameraTrack",
    "ConductorMaterial",
    "ConstantSky",
    "DielectricMaterial",
    "DiffuseMaterial",
    "Direction",
    "EffectName",
    "EnvironmentSky",
    "FileCamera",
    "FilePath",
    "Finite",
    "GradientSky",
    "Ior",
    "Light",
    "Material",
    "MeshFile",
    "MirrorMaterial",
    "Name",
    "NonNegative",
    "NormalMap",
    "ObjectKeyframe",
    "ObjectTrack",
    "Plane",
    "PlasticMaterial",
    "PointLight",
    "Positive",
    "PositiveVec3",
    "Radiance",
    "Rectangle",
    "Reflectance",
    "RenderSettings",
    "Roughness",
    "SceneCamera",
    "SceneFile",
    "SceneObject",
    "Shape",
    "Sky",
    "Sphere",
    "SpotLight",
    "Strict",
    "SunLight",
    "Texture",
    "Time",
    "Transform",
    "Unit",
    "Vec3",
    "Vec4",
    "Vec4Row",
    "override",
]
"""The format's public names: the models defined here and those of its parts (``format_base``,
``format_materials``, ``format_lights``, ``format_animation``), which are used through here."""

FORMAT = "tilerender/1"


class MeshFile(Strict):
    """Triangles from a file (OBJ, PLY, STL, glTF, GLB), relative to the scene file, with the
    file's shading normals or ones smoothed by angle (docs/scene-format.md)."""

    type: Literal["file"] = "file"
    path: FilePath
    normals: Literal["file", "flat"] = Field(
        default="file",
        description="file: shade with the file's vertex normals (glTF NORMAL, OBJ vn, PLY "
        "nx ny nz) where it has them; flat: ignore them and shade every triangle flat",
    )
    smooth_angle: float | None = Field(
        default=None,
        gt=0.0,
        le=180.0,
        allow_inf_nan=False,
        description="Degrees: for meshes without normals in the file, faces meeting at an edge "
        "at less than this angle are shaded smooth across it, sharper edges stay creased "
        "(default: such meshes shade flat)",
    )
    lights: bool = Field(
        default=False,
        description="Add the glTF file's KHR_lights_punctual lights to the scene's, placed by "
        "the object's transform (the object and its parents must be static)",
    )

    @model_validator(mode="after")
    def _check(self) -> "MeshFile":
        if self.normals == "flat" and self.smooth_angle is not None:
            raise ValueError('smooth_angle smooths the shading, normals "flat" asks for none: '
                             "give one of them")  # fmt: skip
        return self


class Rectangle(Strict):
    """A rectangle centred at the origin in the xy plane, facing +z."""

    type: Literal["rectangle"]
    size: tuple[Positive, Positive] = (2.0, 2.0)


class Box(Strict):
    """An axis-aligned box centred at the origin, faces pointing outward."""

    type: Literal["box"]
    size: tuple[Positive, Positive, Positive] = (2.0, 2.0, 2.0)


class Sphere(Strict):
    """An icosphere centred at the origin."""

    type: Literal["sphere"]
    radius: Positive = 1.0
    subdivisions: int = Field(default=4, ge=0, le=config.MAX_SPHERE_SUBDIVISIONS)
    smooth: bool = Field(
        default=False,
        description="Shade with the sphere's normals at the vertices, interpolated (round "
        "however few its triangles); false: flat facets",
    )


class Plane(Strict):
    """A large square in the xz plane through the origin, facing +y (a ground plane)."""

    type: Literal["plane"]
    size: Positive = 100.0


Shape = Annotated[MeshFile | Rectangle | Box | Sphere | Plane, Field(discriminator="type")]


class SceneObject(Strict):
    name: str = Field(default="", max_length=MAX_NAME)
    shape: Shape | str = Field(
        description="A built-in shape, a mesh file, or a mesh file's path as a plain string"
    )
    material: Name | None = Field(
        default=None,
        description="Name of a material; left out for a mesh file, the file's own materials "
        "(glTF PBR or OBJ/MTL, docs/materials.md)",
    )
    transform: Transform = Transform()
    kind: Literal["static", "rigid", "deformable", "dynamic"] = Field(
        default="static",
        description="static: never moves (baked into one BVH); rigid: moves as a whole; "
        "deformable: its vertices move; dynamic: its topology changes",
    )
    parent: Name | None = Field(
        default=None,
        description="Name of an earlier object: this object's transform is relative to it",
    )

    @field_validator("shape", mode="before")
    @classmethod
    def _path_shorthand(cls, value):
        return {"type": "file", "path": value} if isinstance(value, str) else value

    @model_validator(mode="after")
    def _check(self) -> "SceneObject":
        if self.material is None and not isinstance(self.shape, MeshFile):
            raise ValueError("a built-in shape needs a material (only a mesh file may use its own)")
        return self


class Camera(Strict):
    position: Vec3 = (0.0, 0.0, 5.0)
    look_at: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, 1.0, 0.0)
    vfov_deg: float = Field(default=40.0, gt=0.0, lt=180.0, description="Vertical field of view")
    width: int = Field(default=640, ge=1, le=config.MAX_IMAGE_SIDE)
    height: int = Field(default=480, ge=1, le=config.MAX_IMAGE_SIDE)
    aperture_radius: NonNegative = Field(
        default=0.0, description="Radius of the thin lens in scene units; 0 is a pinhole"
    )
    focus_distance: Positive | None = Field(
        default=None,
        description="Distance of the plane in focus along the view direction "
        "(default: the distance from position to look_at)",
    )

    @model_validator(mode="after")
    def _check(self) -> "Camera":
        if self.width * self.height > config.MAX_PIXELS:
            raise ValueError(f"width * height must be at most {config.MAX_PIXELS} pixels")
        forward = np.subtract(self.look_at, self.position)
        if not portable.norm(forward) > 0.0:
            raise ValueError("look_at must differ from position")
        if not portable.norm(portable.cross(portable.normalized(forward), self.up)) > 1e-9:
            raise ValueError("up must not be parallel to the viewing direction")
        return self


class FileCamera(Strict):
    """The view of a perspective camera in the glTF file of an object, placed by the object's
    transform; the image size and lens are the scene's (docs/scene-format.md)."""

    from_object: Name = Field(description="Name of a static object whose shape is a glTF file")
    name: Name | None = Field(
        default=None,
        description="The file's camera, by its name or its node's (default: the first "
        "perspective camera of the file's scene)",
    )
    width: int = Field(default=640, ge=1, le=config.MAX_IMAGE_SIDE)
    height: int = Field(default=480, ge=1, le=config.MAX_IMAGE_SIDE)
    aperture_radius: NonNegative = Field(
        default=0.0, description="Radius of the thin lens in scene units; 0 is a pinhole"
    )
    focus_distance: Positive | None = Field(
        default=None, description="Distance of the plane in focus; needed with an aperture"
    )

    @model_validator(mode="after")
    def _check(self) -> "FileCamera":
        if self.width * self.height > config.MAX_PIXELS:
            raise ValueError(f"width * height must be at most {config.MAX_PIXELS} pixels")
        if self.aperture_radius > 0.0 and self.focus_distance is None:
            raise ValueError("an aperture needs a focus_distance (the file's camera has none)")
        return self


def _camera_kind(value) -> str:
    if isinstance(value, dict):
        return "file" if "from_object" in value else "view"
    return "file" if isinstance(value, FileCamera) else "view"


SceneCamera = Annotated[
    Annotated[Camera, Tag("view")] | Annotated[FileCamera, Tag("file")],
    Discriminator(_camera_kind),
]
"""A scene file's camera: a view of its own, or a glTF file's camera (``from_object``)."""


EffectName = Literal[
    "area_lights",
    "point_lights",
    "sun",
    "sky",
    "shadows",
    "indirect",
    "refraction",
    "absorption",
    "textures",
    "shading_normals",
    "normal_maps",
    "shadow_terminator",
    "normal_bending",
    "alpha_test",
]
"""Effects a user may switch off (docs/effects.md)."""


class RenderSettings(Strict):
    spp: int = Field(default=64, ge=1, le=config.MAX_SPP, description="Samples per pixel")
    max_depth: int = Field(
        default=8,
        ge=1,
        le=config.MAX_DEPTH,
        description="Path vertices after the camera: 1 = emitters only, 2 = direct light",
    )
    rr_depth: int = Field(
        default=5,
        ge=1,
        le=config.MAX_DEPTH,
        description="Russian roulette starts at paths of this many vertices",
    )
    seed: int = Field(default=0, ge=0, lt=2**63)
    integrator: Literal[INTEGRATORS] = Field(
        default="path",
        description="path (NEE + MIS + Russian roulette), direct (one bounce), whitted (direct "
        "light and perfect specular recursion), ao (ambient occlusion), or a debug output: "
        "albedo, normal, depth, cost",
    )
    effects: dict[EffectName, bool] = Field(
        default_factory=dict,
        description="Effects switched off on purpose (name -> false); docs/effects.md",
    )
    effect_plan: bool = Field(
        default=True,
        description="Simulate only the effects the scene needs; false runs every effect "
        "(the same image in expectation, slower: for checking the plan)",
    )
    kernel: Literal[KERNELS] = Field(
        default="auto",
        description="How paths are traced: single (one path at a time), stream (a stream of "
        "paths a stage at a time), or auto (the choice the measured rule makes for the "
        "integrator and scene; docs/performance.md). The same image bit for bit either way",
    )
    light_sampler: Literal[LIGHT_SAMPLERS] = Field(
        default="auto",
        description="How light samples pick emissive triangles: power (by their power), tree "
        "(a light tree, by their importance as seen from the point), or auto (the tree where "
        "the scene has enough emissive triangles to gain; docs/effects.md). The same image in "
        "expectation either way",
    )
    aovs: bool = Field(
        default=False,
        description="Also render the AOV layers albedo, normal, depth, position, alpha, "
        "object_id and material_id from the same paths (path, direct, whitted and cost "
        "integrators; docs/outputs.md)",
    )
    denoise: Literal[DENOISE] = Field(
        default="off",
        description="Denoise the assembled frame with Open Image Denoise at this quality "
        "(fast, balanced, high), guided by the albedo and normal AOVs where the integrator "
        "gives them; the beauty layer is kept (docs/denoising.md)",
    )
    denoise_prefilter: Literal[DENOISE_PREFILTER] = Field(
        default="auto",
        description="Prefilter the denoiser's albedo and normal guides before the beauty is "
        "denoised (OIDN's recipe for noisy guides): auto where they are noisy (both with a lens "
        "aperture, a normal map or a blended surface, the albedo alone with textures only), on "
        "(both), off, or "
        "albedo (the albedo alone, the normal counted clean) (docs/denoising.md)",
    )
    adaptive: Literal[ADAPTIVE] = Field(
        default="auto",
        description="Adaptive sampling in progressive renders (a target error or a time "
        "budget): each wave gives pixels samples by their estimated share of the error; auto "
        "where it is predicted to win, on, or off (true and false mean on and off; "
        "docs/accuracy.md). Renders of a fixed spp sample uniformly",
    )
    ao_samples: int = Field(
        default=4, ge=1, le=1024, description="Ambient occlusion rays per camera sample"
    )
    ao_distance: Positive = Field(
        default=0.1,
        description="Ambient occlusion ray length, as a fraction of the scene's bounding-box "
        "diagonal",
    )

    @property
    def renders_aovs(self) -> bool:
        """Whether the kernel records AOVs: asked for, or guides for the denoiser."""
        return self.aovs or (self.denoise != "off" and self.integrator in AOV_INTEGRATORS)

    @model_validator(mode="after")
    def _aovs_possible(self) -> "RenderSettings":
        if self.aovs and self.integrator not in AOV_INTEGRATORS:
            raise ValueError(
                f"the {self.integrator} integrator gives no AOVs (they come from the paths of "
                f"{', '.join(AOV_INTEGRATORS)})"
            )
        if self.renders_aovs and self.kernel == "stream":
            raise ValueError(
                "the stream kernel does not record AOVs yet (aovs or denoise ask for them); "
                "use kernel auto or single"
            )
        return self

    @field_validator("adaptive", mode="before")
    @classmethod
    def _adaptive_bool(cls, value):
        if isinstance(value, bool):
            return "on" if value else "off"
        return value

    @field_validator("effects")
    @classmethod
    def _only_off(cls, value):
        on = sorted(name for name, enabled in value.items() if enabled)
        if on:
            raise ValueError(
                f"effects can only be switched off (false); {', '.join(on)} would be on anyway "
                "where the scene needs it"
            )
        return value


class SceneFile(Strict):
    """A tilerender scene: objects with materials, a camera, render settings, a sky and an
    optional keyframe animation."""

    format: Literal["tilerender/1"] = FORMAT
    camera: SceneCamera = Camera()
    render: RenderSettings = RenderSettings()
    sky: Sky = ConstantSky()
    lights: list[Light] = Field(
        default_factory=list,
        description="Point, spot and sun lights (emitting surfaces are materials with emission)",
    )
    materials: dict[Name, Material] = Field(
        min_length=1, description=f"Material name (at most {MAX_NAME} characters) -> material"
    )
    objects: list[SceneObject] = Field(min_length=1)
    animation: AnimationSettings | None = None

    @model_validator(mode="after")
    def _check_references(self) -> "SceneFile":
        for i, obj in enumerate(self.objects):
            if obj.material is not None and obj.material not in self.materials:
                known = ", ".join(sorted(self.materials))
                raise ValueError(
                    f"objects[{i}] uses material {obj.material!r}, which is not defined "
                    f"(defined: {known})"
                )
        if isinstance(self.camera, FileCamera):
            named = [o for o in self.objects if o.name == self.camera.from_object]
            if not named or not isinstance(named[-1].shape, MeshFile):
                raise ValueError(
                    f"camera.from_object: no object named {self.camera.from_object!r} has a "
                    "mesh file for its shape"
                )
        return self


def override(model: Strict, **changes) -> Strict:
    """A copy of ``model`` with ``changes`` (``None`` values ignored), validated like the input.

    Raises pydantic's ValidationError for a value the model would refuse in a file.
    """
    data = model.model_dump()
    data.update({k: v for k, v in changes.items() if v is not None})
    return type(model).model_validate(data)
