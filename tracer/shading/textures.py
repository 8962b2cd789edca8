"""Base-colour textures: reading images, packing them for kernels, and the bilinear lookup.

A scene state holds each image as uint8 (H, W, 3), sRGB-encoded, row 0 the top of the image
(``SceneState.textures``). Compiling packs every texture the materials use into one flat float32
array of linear RGB texels with a row of ``(offset, width, height, wrap)`` per texture
(:class:`TextureTable`). Kernels look a texture up at the hit's interpolated UV
(:func:`texture_at`): ``u`` runs left to right, ``v`` bottom to top, texel centres at
``((i + 0.5) / W, 1 - (j + 0.5) / H)``, bilinear between the four nearest texels, and outside
[0, 1] either repeated or clamped to the edge texels. docs/materials.md states the conventions.

A material's alpha (``fmt.Alpha``) reads an image's alpha channel, held as a grey image of its
own (``alpha_image_name``) and packed linearly like a normal map; the table's ``alpha`` rows are
what ``tracer.shading.alpha`` tests at hits.
"""

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from tracer import config
from tracer.compiled.arrays import pick
from tracer.errors import SceneError
from tracer.kernel.jit import jit_inline
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.model import frozen_array

REPEAT = 0
CLAMP = 1
WRAP_MODES = {"repeat": REPEAT, "clamp": CLAMP}
UV_LIMIT = 1e15
"""A scaled UV of larger magnitude (or NaN) is looked up at 0: past it a float64 has no
fraction left to tile with."""
OPAQUE = 0
MASK = 1
BLEND = 2
ALPHA_MODES = {"mask": MASK, "blend": BLEND}
MODE, CUTOFF, VALUE, ENTRY = range(4)
"""Columns of ``TextureTable.alpha``: mode, cutoff, value, the alpha image's entry (or -1)."""
ALPHA_SUFFIX = "#alpha"
NO_ALPHA = np.zeros((0, 4), dtype=np.float64)
"""The kernels' alpha table of a plan without ``flags.ALPHA_TEST``: no hit is tested."""


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """Linear values (float32) of 8-bit sRGB-encoded ``values`` (IEC 61966-2-1)."""
    c = np.arange(256, dtype=np.float64) / 255.0
    curve = portable.elementwise(lambda x: math.pow(x, 2.4), (c + 0.055) / 1.055)
    table = np.where(c <= 0.04045, c / 12.92, curve).astype(np.float32)
    return table[np.asarray(values, dtype=np.uint8)]


def _check_size(image: Image.Image, label: str) -> None:
    width, height = image.size
    if not (0 < width <= config.MAX_TEXTURE_SIDE and 0 < height <= config.MAX_TEXTURE_SIDE):
        raise SceneError(
            f"{label}: the image is {width}x{height}; textures are 1 to "
            f"{config.MAX_TEXTURE_SIDE} pixels a side"
        )
    if width * height > config.MAX_TEXTURE_PIXELS:
        raise SceneError(
            f"{label}: the image has {width * height} pixels, more than the limit of "
            f"{config.MAX_TEXTURE_PIXELS}"
        )


def texture_from_image(image: Image.Image, label: str) -> np.ndarray:
    """An image as texture pixels: uint8 (H, W, 3), read-only. Grey images become grey RGB,
    palettes are expanded, alpha is dropped (``alpha_from_image`` reads it); 16-bit grey is
    rounded to 8 bits."""
    _check_size(image, label)
    try:
        if image.mode.startswith("I"):  # 16- or 32-bit integer grey
            grey = np.asarray(image, dtype=np.float64)
            grey = np.clip(np.rint(grey / 257.0), 0, 255).astype(np.uint8)
            pixels = np.repeat(grey[:, :, None], 3, axis=2)
        elif image.mode == "F":
            raise SceneError(
                f"{label}: floating-point images are not supported (use an 8-bit sRGB image)"
            )
        else:
            pixels = np.asarray(image.convert("RGB"), dtype=np.uint8)
    except (OSError, ValueError) as exc:  # truncated or corrupt image data
        raise SceneError(f"{label}: cannot decode the image ({exc})") from None
    return frozen_array(pixels, np.uint8)


def alpha_image_name(file: str) -> str:
    """The name of the grey image holding the alpha channel of the image named ``file``."""
    return file + ALPHA_SUFFIX


def alpha_from_image(image: Image.Image, label: str) -> np.ndarray | None:
    """An image's alpha channel as a grey texture, uint8 (H, W, 3) read-only; None if the image
    has no alpha (no alpha band, no palette transparency)."""
    _check_size(image, label)
    if "A" not in image.getbands() and "transparency" not in image.info:
        return None
    try:
        alpha = np.asarray(image.convert("RGBA"), dtype=np.uint8)[:, :, 3]
    except (OSError, ValueError) as exc:
        raise SceneError(f"{label}: cannot decode the image ({exc})") from None
    return frozen_array(np.repeat(alpha[:, :, None], 3, axis=2), np.uint8)


def read_texture(path: Path, label: str, alpha: bool = False) -> np.ndarray:
    """The texture pixels of the image file ``path`` (any format Pillow reads), or with
    ``alpha`` its alpha channel (``alpha_from_image``; an image without one is refused)."""
    try:
        with Image.open(path) as image:
            if not alpha:
                return texture_from_image(image, label)
            pixels = alpha_from_image(image, label)
            if pixels is None:
                raise SceneError(f"{label}: the image has no alpha channel")
            return pixels
    except UnidentifiedImageError:
        raise SceneError(f"{label}: not an image file Pillow can read") from None
    except Image.DecompressionBombError as exc:
        raise SceneError(f"{label}: {exc}") from None
    except OSError as exc:
        raise SceneError(f"{label}: cannot read the image ({exc})") from None


def material_texture(material: fmt.Material) -> fmt.Texture | None:
    """The material's base-colour texture, or None."""
    return getattr(material, "texture", None)


def alpha_texture(material: fmt.Material) -> fmt.Texture | None:
    """The material's alpha texture, its ``file`` the scene image of its alpha channel (or
    None)."""
    alpha = getattr(material, "alpha", None)
    if alpha is None or alpha.texture is None:
        return None
    return alpha.texture.model_copy(update={"file": alpha_image_name(alpha.texture.file)})


def linear_texels(values: np.ndarray) -> np.ndarray:
    """8-bit ``values`` read as linear in [0, 1] (float32; normal maps are not sRGB)."""
    return (np.arange(256, dtype=np.float32) / np.float32(255.0))[np.asarray(values, np.uint8)]


@dataclass(frozen=True, eq=False)
class TextureTable:
    """Textures packed for kernels; one entry per distinct (file, wrap, scale) materials use.

    ``pixels`` float32 (N, 3) linear RGB, each image's rows top to bottom; ``info`` int64
    (T, 4): first texel, width, height and wrap mode (``REPEAT``, ``CLAMP``); ``scale`` float64
    (T, 2): the UV scale; ``material`` int32 (Q,): each material's entry, or -1;
    ``normal_map`` int32 (Q,) its normal map's entry (texels read linearly), or -1,
    ``normal_strength`` float64 (Q,) the map's strength, and ``alpha`` float64 (Q, 4) each
    material's alpha (columns ``MODE``, ``CUTOFF``, ``VALUE``, ``ENTRY``: its alpha image's
    entry, texels read linearly, or -1). ``sources`` is what it was packed from (compared by
    identity for reuse)."""

    sources: tuple
    pixels: np.ndarray
    info: np.ndarray
    scale: np.ndarray
    material: np.ndarray
    normal_map: np.ndarray
    normal_strength: np.ndarray
    alpha: np.ndarray

    def fields(self) -> dict[str, np.ndarray]:
        """The ``SceneArrays`` fields made from the table."""
        return {
            "mat_texture": self.material,
            "mat_normal_map": self.normal_map,
            "mat_normal_strength": self.normal_strength,
            "tex_pixels": self.pixels,
            "tex_info": self.info,
            "tex_scale": self.scale,
            "mat_alpha": NO_ALPHA,
        }


def texture_table(
    textures, materials: list[fmt.Material], previous: TextureTable | None = None
) -> TextureTable:
    """Pack the textures ``materials`` use (``textures``: name -> uint8 pixels), reusing the
    pixels of ``previous`` when it was packed from the very same images."""
    entries: dict[tuple, int] = {}
    material = np.full(len(materials), -1, dtype=np.int32)
    normal_map = np.full(len(materials), -1, dtype=np.int32)
    normal_strength = np.zeros(len(materials), dtype=np.float64)
    alpha_entry = np.full(len(materials), -1, dtype=np.int32)
    for i, m in enumerate(materials):
        pairs = ((material, material_texture(m), False),
                 (normal_map, getattr(m, "normal_map", None), True),
                 (alpha_entry, alpha_texture(m), True))  # fmt: skip
        for column, texture, linear in pairs:
            if texture is not None:
                key = (texture.file, linear, texture.wrap, tuple(texture.scale))
                column[i] = entries.setdefault(key, len(entries))
        if normal_map[i] >= 0:
            normal_strength[i] = m.normal_map.strength
    images = list(dict.fromkeys((file, linear) for file, linear, _, _ in entries))
    missing = [file for file, _ in images if file not in textures]
    if missing:
        raise SceneError(f"texture {missing[0]!r} is not one of the scene's images")
    sources = tuple((file, linear, textures[file]) for file, linear in images)
    info = np.zeros((len(entries), 4), dtype=np.int64)
    scale = np.zeros((len(entries), 2), dtype=np.float64)
    if previous is not None and _same_sources(previous.sources, sources):
        pixels = previous.pixels
    else:
        parts = [(linear_texels if linear else srgb_to_linear)(image).reshape(-1, 3)
                 for _, linear, image in sources]  # fmt: skip
        pixels = np.concatenate(parts) if parts else np.zeros((0, 3), np.float32)
    first = {}
    offset = 0
    for file, linear, image in sources:
        first[file, linear] = offset
        offset += image.shape[0] * image.shape[1]
    for (file, linear, wrap, uv_scale), row in entries.items():
        height, width = textures[file].shape[:2]
        info[row] = (first[file, linear], width, height, WRAP_MODES[wrap])
        scale[row] = uv_scale
    alpha = alpha_rows(materials, alpha_entry)
    return TextureTable(sources, pixels, info, scale, material, normal_map, normal_strength, alpha)


def alpha_rows(materials: list[fmt.Material], entry: np.ndarray) -> np.ndarray:
    """``TextureTable.alpha``: each material's alpha mode, cutoff, value and image entry."""
    rows = np.zeros((len(materials), 4), dtype=np.float64)
    rows[:, ENTRY] = entry
    for i, m in enumerate(materials):
        alpha = getattr(m, "alpha", None)
        if alpha is not None:
            rows[i, :ENTRY] = (ALPHA_MODES[alpha.mode], alpha.cutoff, alpha.value)
    return rows


def _same_sources(a: tuple, b: tuple) -> bool:
    return len(a) == len(b) and all(
        x[0] == y[0] and x[1] == y[1] and x[2] is y[2] for x, y in zip(a, b, strict=True)
    )


@jit_inline
def _wrap_coordinate(x, wrap):
    """``x`` scaled UV -> [0, 1]: its fraction (repeat) or itself clamped (clamp)."""
    if not abs(x) <= UV_LIMIT:
        x = 0.0
    if wrap == REPEAT:
        return x - np.floor(x)
    return min(max(x, 0.0), 1.0)


@jit_inline
def _neighbours(x, size, wrap):
    """The two texel indices around the continuous coordinate ``x`` (texel centres at
    integers) and the weight of the second."""
    f = np.floor(x)
    i0 = np.int64(f)
    i1 = i0 + 1
    if wrap == REPEAT:
        if i0 < 0:
            i0 += size
        if i1 >= size:
            i1 -= size
    else:
        i0 = max(i0, 0)
        i1 = min(i1, size - 1)
    return i0, i1, x - f


@jit_inline
def bilinear(pixels, info, scale, t, u, v):
    """Texture ``t`` of the table at ``(u, v)``: ``(r, g, b)`` float64, bilinear."""
    offset = info[t, 0]
    width = info[t, 1]
    height = info[t, 2]
    wrap = info[t, 3]
    u = _wrap_coordinate(u * scale[t, 0], wrap)
    v = _wrap_coordinate(v * scale[t, 1], wrap)
    x0, x1, fx = _neighbours(u * width - 0.5, width, wrap)
    y0, y1, fy = _neighbours((1.0 - v) * height - 0.5, height, wrap)
    w00 = (1.0 - fx) * (1.0 - fy)
    w01 = fx * (1.0 - fy)
    w10 = (1.0 - fx) * fy
    w11 = fx * fy
    a = offset + y0 * width
    b = offset + y1 * width
    r = (w00 * pixels[a + x0, 0] + w01 * pixels[a + x1, 0] + w10 * pixels[b + x0, 0]
         + w11 * pixels[b + x1, 0])  # fmt: skip
    g = (w00 * pixels[a + x0, 1] + w01 * pixels[a + x1, 1] + w10 * pixels[b + x0, 1]
         + w11 * pixels[b + x1, 1])  # fmt: skip
    bl = (w00 * pixels[a + x0, 2] + w01 * pixels[a + x1, 2] + w10 * pixels[b + x0, 2]
          + w11 * pixels[b + x1, 2])  # fmt: skip
    return (r, g, bl)


@jit_inline
def hit_uv(s, k, j, b0, b1, b2):
    """The UV of instance ``k``'s triangle row ``j`` at barycentrics (b0, b1, b2)."""
    uv = pick(s.tri_uv, s.inst_pool[k])
    u = b0 * uv[j, 0] + b1 * uv[j, 2] + b2 * uv[j, 4]
    v = b0 * uv[j, 1] + b1 * uv[j, 3] + b2 * uv[j, 5]
    return u, v


@jit_inline
def texture_at(s, t, k, j, b0, b1, b2):
    """Texture ``t`` at the hit (instance ``k``, row ``j``, barycentrics): ``(r, g, b)``."""
    u, v = hit_uv(s, k, j, b0, b1, b2)
    return bilinear(s.tex_pixels, s.tex_info, s.tex_scale, t, u, v)


@jit_inline
def textured_albedo(s, mat, albedo, k, j, b0, b1, b2):
    """``albedo`` times material ``mat``'s texture at the hit (unchanged without one)."""
    t = s.mat_texture[mat]
    if t < 0:
        return albedo
    c = texture_at(s, t, k, j, b0, b1, b2)
    return (albedo[0] * c[0], albedo[1] * c[1], albedo[2] * c[2])


def uv_rows(uvs: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """float32 (F, 6): each face's three UVs, ``(u0, v0, u1, v1, u2, v2)``."""
    return np.ascontiguousarray(uvs[faces].reshape(-1, 6), dtype=np.float32)
