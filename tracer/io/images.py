"""Write and read rendered images: PNG (sRGB, 8 bit), EXR (float32 linear), NPY (float32 linear).

Writes are atomic (``tracer.io.files``): a failed or interrupted render never leaves a partial
file.
"""

import json
import math
from pathlib import Path

import numpy as np

from tracer.io.files import atomic_path, output_file
from tracer.kernel.jit import jit

FORMATS = (".png", ".exr", ".npy")


@jit
def _srgb_codes(x, out):
    """sRGB codes of linear values in [0, 1] (the C library's ``pow``, not numpy's per-CPU SIMD)."""
    for i in range(x.size):
        v = x[i]
        s = 12.92 * v if v <= 0.0031308 else 1.055 * math.pow(v, 1.0 / 2.4) - 0.055
        out[i] = np.uint8(np.rint(s * 255.0))


def linear_to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """Clamp linear RGB to [0, 1] and encode with the sRGB transfer curve as uint8."""
    x = np.clip(np.nan_to_num(np.asarray(rgb, np.float64), nan=0.0), 0.0, 1.0)
    out = np.empty(x.shape, np.uint8)
    _srgb_codes(np.ascontiguousarray(x).reshape(-1), out.reshape(-1))
    return out


def check_output_path(path: str | Path) -> Path:
    """The output path, if its extension names a format we write; ValueError otherwise."""
    return output_file(path, FORMATS, "image")


def write_image(path: str | Path, rgb: np.ndarray, metadata: dict | None = None) -> Path:
    """Write float32 linear RGB, shape (H, W, 3), row 0 at the top, in the format of the suffix.

    ``metadata`` (JSON-serialisable) is stored in the file where the format allows it: a PNG
    text chunk or an EXR header attribute, both named ``tilerender``.
    """
    path = check_output_path(path)
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {rgb.shape}")
    text = json.dumps(metadata or {}, sort_keys=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        suffix = path.suffix.lower()
        if suffix == ".npy":
            with open(tmp, "wb") as f:
                np.save(f, rgb)
        elif suffix == ".png":
            from PIL import Image, PngImagePlugin

            info = PngImagePlugin.PngInfo()
            info.add_text("tilerender", text)
            Image.fromarray(linear_to_srgb8(rgb), mode="RGB").save(tmp, format="PNG", pnginfo=info)
        else:
            import OpenEXR

            header = {
                "compression": OpenEXR.ZIP_COMPRESSION,
                "type": OpenEXR.scanlineimage,
                "tilerender": text,
            }
            OpenEXR.File(header, {"RGB": rgb}).write(str(tmp))
    return path


def read_image(path: str | Path) -> np.ndarray:
    """Read an image written by :func:`write_image` as float32 (H, W, 3) (PNG stays sRGB/255;
    an EXR's default layer, without its alpha)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return np.load(path)
    if suffix == ".exr":
        import OpenEXR

        with OpenEXR.File(str(path)) as f:
            channels = f.channels()  # R, G, B grouped as "RGB", or "RGBA" with an alpha
            rgb = channels["RGB"] if "RGB" in channels else channels["RGBA"]
            return np.array(rgb.pixels[..., :3], dtype=np.float32)
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0
