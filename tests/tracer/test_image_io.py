"""Image files (``tracer.io.images``): exact float round trips for NPY and EXR, sRGB 8-bit PNG,
metadata in the file, and atomic writes that never leave a partial or temporary file."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from tracer.io import images as image_io
from tracer.io.images import check_output_path, linear_to_srgb8, read_image, write_image

METADATA = {"renderer": "tilerender", "render": {"spp": 3, "seed": 7}, "note": "caf\u00e9"}


def random_image(seed: int, height: int, width: int) -> np.ndarray:
    """Linear radiance spanning many magnitudes, with exact zeros and values above 1."""
    rng = np.random.default_rng(seed)
    rgb = 10.0 ** rng.uniform(-30, 5, size=(height, width, 3))
    rgb[rng.uniform(size=rgb.shape) < 0.1] = 0.0
    return rgb.astype(np.float32)


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """The inverse sRGB transfer curve (IEC 61966-2-1), in float64."""
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def only_file(directory, name):
    """The directory holds exactly ``name`` (no temporary files)."""
    assert sorted(p.name for p in directory.iterdir()) == [name]


@settings(max_examples=15)
@given(seed=st.integers(0, 2**32 - 1), height=st.integers(1, 9), width=st.integers(1, 9))
@pytest.mark.parametrize("suffix", [".npy", ".exr"])
def test_float_round_trip_is_exact(tmp_path_factory, suffix, seed, height, width):
    """NPY and EXR store float32 linear RGB exactly (shape, dtype, every bit), row 0 first."""
    directory = tmp_path_factory.mktemp("img")
    rgb = random_image(seed, height, width)
    path = write_image(directory / f"out{suffix}", rgb, METADATA)
    back = read_image(path)
    assert back.dtype == np.float32 and back.shape == (height, width, 3)
    assert np.array_equal(back, rgb)
    only_file(directory, f"out{suffix}")


def test_png_round_trip_is_srgb(tmp_path):
    """PNG holds linear_to_srgb8 of the image: 8-bit sRGB, read back as sRGB / 255."""
    rgb = random_image(1, 7, 5) * np.float32(1e-5)
    rgb[0, 0] = [0.5, 1.0, 2.0]
    path = write_image(tmp_path / "out.png", rgb, METADATA)
    back = read_image(path)
    assert back.shape == (7, 5, 3)
    assert np.array_equal(back, linear_to_srgb8(rgb).astype(np.float32) / 255.0)
    assert np.array_equal(np.round(back[0, 0] * 255), [188, 255, 255])
    with Image.open(path) as image:
        assert image.mode == "RGB" and image.size == (5, 7)


@pytest.mark.parametrize("suffix", [".png", ".exr", ".npy"])
def test_row_zero_is_the_top(tmp_path, suffix):
    """Row 0 of the array is the top row of the picture and column 0 its left edge."""
    rgb = np.zeros((4, 6, 3), np.float32)
    rgb[0, 1] = 1.0
    path = write_image(tmp_path / f"out{suffix}", rgb)
    if suffix == ".png":
        with Image.open(path) as image:
            assert image.getpixel((1, 0)) == (255, 255, 255)
            assert image.getpixel((1, 3)) == (0, 0, 0)
    back = read_image(path)
    assert back[0, 1].tolist() == [1.0, 1.0, 1.0] and back.sum() == 3.0


def test_linear_to_srgb8_known_values():
    """The sRGB curve at known points; clamping below 0 and above 1; NaN becomes black."""
    values = np.array([0.0, 0.0031308, 0.5, 1.0, -1.0, 7.0, np.nan, np.inf, -np.inf])
    assert linear_to_srgb8(values).tolist() == [0, 10, 188, 255, 0, 255, 0, 255, 0]
    assert linear_to_srgb8(values).dtype == np.uint8


def test_linear_to_srgb8_inverts_the_srgb_curve():
    """Every 8-bit code survives decoding to linear and encoding again, and encoding is
    monotonic."""
    codes = np.arange(256)
    assert np.array_equal(linear_to_srgb8(srgb_to_linear(codes / 255.0)), codes)
    ramp = linear_to_srgb8(np.linspace(-0.1, 1.1, 10001))
    assert (np.diff(ramp.astype(int)) >= 0).all()


def test_png_metadata(tmp_path):
    """PNG keeps the metadata as JSON in a text chunk named 'tilerender'."""
    path = write_image(tmp_path / "out.png", np.zeros((2, 2, 3), np.float32), METADATA)
    with Image.open(path) as image:
        assert json.loads(image.text["tilerender"]) == METADATA


def test_exr_metadata(tmp_path):
    """EXR keeps the metadata as JSON in a header attribute named 'tilerender'."""
    import OpenEXR

    path = write_image(tmp_path / "out.exr", np.zeros((2, 2, 3), np.float32), METADATA)
    with OpenEXR.File(str(path)) as f:
        assert json.loads(f.header()["tilerender"]) == METADATA


def test_uppercase_suffix(tmp_path):
    """The format follows the extension case-insensitively."""
    rgb = random_image(2, 3, 3)
    assert np.array_equal(read_image(write_image(tmp_path / "OUT.NPY", rgb)), rgb)
    with Image.open(write_image(tmp_path / "OUT.PNG", rgb)) as image:
        assert image.format == "PNG"


@pytest.mark.parametrize("name", ["out.jpg", "out", "out.png.tmp", "out.tiff"])
def test_unknown_extension(tmp_path, name):
    """Unknown extensions raise ValueError naming the known ones, and nothing is written."""
    with pytest.raises(ValueError, match=r"\.png, \.exr, \.npy"):
        check_output_path(tmp_path / name)
    with pytest.raises(ValueError, match="unknown image format"):
        write_image(tmp_path / name, np.zeros((2, 2, 3), np.float32))
    assert list(tmp_path.iterdir()) == []


def test_directory_is_not_an_output(tmp_path):
    """A directory named like an image is refused."""
    (tmp_path / "out.png").mkdir()
    with pytest.raises(ValueError, match="directory"):
        check_output_path(tmp_path / "out.png")


@pytest.mark.parametrize("shape", [(4, 4), (4, 4, 4), (4, 4, 1), (2, 2, 2, 3)])
def test_bad_shapes(tmp_path, shape):
    """Arrays that are not (H, W, 3) are refused and nothing is written."""
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        write_image(tmp_path / "out.npy", np.zeros(shape, np.float32))
    assert list(tmp_path.iterdir()) == []


def test_overwrite_replaces_the_file(tmp_path):
    """Writing over an existing image replaces it completely."""
    path = tmp_path / "out.npy"
    write_image(path, random_image(3, 8, 8))
    new = random_image(4, 2, 3)
    write_image(path, new)
    assert np.array_equal(read_image(path), new)
    only_file(tmp_path, "out.npy")


class Boom(RuntimeError):
    pass


def failing_after_partial_write(real, target_arg: int):
    """Wrap a writer so it writes its file (argument ``target_arg``), cuts it short, then
    fails, like a full disk."""

    def writer(*args, **kwargs):
        real(*args, **kwargs)
        target = args[target_arg]
        if hasattr(target, "flush"):
            target.flush()
            target.truncate(10)
        else:
            with open(target, "r+b") as f:
                f.truncate(10)
        raise Boom("disk full")

    return writer


@pytest.mark.parametrize("suffix", [".npy", ".png", ".exr"])
@pytest.mark.parametrize("existing", [False, True], ids=["new", "existing"])
def test_failed_write_leaves_nothing_behind(tmp_path, monkeypatch, suffix, existing):
    """A write that fails half way leaves no partial image and no temporary file; an image
    that was already there is left untouched."""
    path = tmp_path / f"out{suffix}"
    old = random_image(5, 3, 4)
    if existing:
        write_image(path, old)
        before = path.read_bytes()
    if suffix == ".npy":
        monkeypatch.setattr(np, "save", failing_after_partial_write(np.save, 0))
    elif suffix == ".png":
        monkeypatch.setattr(Image.Image, "save", failing_after_partial_write(Image.Image.save, 1))
    else:
        import OpenEXR

        monkeypatch.setattr(
            OpenEXR.File, "write", failing_after_partial_write(OpenEXR.File.write, 1)
        )
    with pytest.raises(Boom):
        write_image(path, random_image(6, 5, 5), METADATA)
    if existing:
        only_file(tmp_path, path.name)
        assert path.read_bytes() == before
    else:
        assert list(tmp_path.iterdir()) == []


def test_unserialisable_metadata_writes_nothing(tmp_path):
    """Metadata that is not JSON raises before anything touches the disk."""
    with pytest.raises(TypeError):
        write_image(tmp_path / "out.png", np.zeros((2, 2, 3), np.float32), {"x": object()})
    assert list(tmp_path.iterdir()) == []


def test_formats_are_the_documented_ones():
    """The writer knows exactly the formats the README documents."""
    assert set(image_io.FORMATS) == {".png", ".exr", ".npy"}
