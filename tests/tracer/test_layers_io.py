"""Frame layers files (``tracer.io.layers``): bit-exact round trips of every layer through a
multilayer EXR and a NumPy bundle, the EXR's channel names, plain EXRs read as the beauty, the
layer contract's errors, atomic writes, and each layer as a viewable RGB image."""

import json

import numpy as np
import OpenEXR
import pytest

from tests.helpers import SCENES, tiny_scene
from tracer.compiled.scene import compile_scene
from tracer.io.images import read_image, write_image
from tracer.io.layers import (
    ID_LAYERS,
    LAYER_FORMATS,
    LAYERS,
    check_layers,
    layer_as_rgb,
    read_layers,
    write_layers,
)
from tracer.io.metadata import id_names
from tracer.post.frame_layers import frame_layers
from tracer.render import render_pixels
from tracer.scene.format import SceneFile, override
from tracer.scene.loader import scene_from_file_model

METADATA = {"renderer": "tilerender", "render": {"spp": 3, "seed": 7}, "note": "caf\u00e9"}

CHANNELS = [
    "R", "G", "B",
    "denoised.R", "denoised.G", "denoised.B",
    "albedo.R", "albedo.G", "albedo.B",
    "normal.X", "normal.Y", "normal.Z",
    "Z",
    "position.X", "position.Y", "position.Z",
    "alpha.A",
    "object_id.X",
    "material_id.X",
]  # fmt: skip
"""The multilayer EXR's channels, written out by hand (not derived from the module)."""


def random_layers(seed: int, height: int, width: int, names=tuple(LAYERS)) -> dict:
    """Signed values spanning many magnitudes, each layer different, with exact zeros, -0.0,
    denormals, infinities and NaNs (one with a payload) in the beauty; ids from -1 to 2**24."""
    rng = np.random.default_rng(seed)
    layers = {}
    for name in names:
        shape = (height, width, 3) if LAYERS[name] == 3 else (height, width)
        x = rng.choice([-1.0, 1.0], size=shape) * 10.0 ** rng.uniform(-30, 5, size=shape)
        x[rng.uniform(size=shape) < 0.1] = 0.0
        if name in ID_LAYERS:
            x = rng.integers(-1, 2**24, size=shape, endpoint=True)
        layers[name] = x.astype(np.float32)
    special = np.array([np.nan, np.inf, -np.inf, -0.0, 1e-45, -1e-40], np.float32)
    special[0] = np.uint32(0x7FC12345).view(np.float32)
    flat = layers["beauty"].reshape(-1)
    flat[: min(flat.size, special.size)] = special[: flat.size]
    return layers


def bits(array: np.ndarray) -> np.ndarray:
    return np.asarray(array, np.float32).view(np.uint32)


def only_file(directory, name):
    """The directory holds exactly ``name`` (no temporary files)."""
    assert sorted(p.name for p in directory.iterdir()) == [name]


@pytest.mark.parametrize("suffix", LAYER_FORMATS)
@pytest.mark.parametrize("size", [(1, 1), (5, 7)])
@pytest.mark.parametrize(
    "names", [tuple(LAYERS), ("beauty",), ("beauty", "depth", "normal")], ids=["all", "1", "3"]
)
def test_round_trip_is_bit_exact(tmp_path, suffix, size, names):
    """Every layer comes back with its shape, float32 and every bit (NaN payloads included), in
    the contract's order, with the metadata."""
    layers = random_layers(sum(size), *size, names=names)
    path = write_layers(tmp_path / f"frame{suffix}", dict(reversed(layers.items())), METADATA)
    back, metadata = read_layers(path)
    assert list(back) == [name for name in LAYERS if name in names]
    for name in names:
        assert back[name].dtype == np.float32 and back[name].shape == layers[name].shape
        assert np.array_equal(bits(back[name]), bits(layers[name])), name
    assert metadata == METADATA
    only_file(tmp_path, f"frame{suffix}")


@pytest.mark.parametrize("suffix", LAYER_FORMATS)
def test_no_metadata_reads_as_empty(tmp_path, suffix):
    layers = random_layers(1, 2, 3, names=("beauty",))
    assert read_layers(write_layers(tmp_path / f"f{suffix}", layers))[1] == {}


def test_exr_channels_and_header(tmp_path):
    """The EXR has exactly the compositor-style channels, all float32, ZIP, scanline, and the
    metadata as the 'tilerender' attribute."""
    path = write_layers(tmp_path / "frame.exr", random_layers(2, 4, 3), METADATA)
    with OpenEXR.File(str(path), header_only=True) as f:
        header = dict(f.header())  # closing the file empties its header()
    assert sorted(c.name for c in header["channels"]) == sorted(CHANNELS)
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION
    assert header["type"] == OpenEXR.scanlineimage
    assert json.loads(header["tilerender"]) == METADATA
    with OpenEXR.File(str(path), separate_channels=True) as f:
        types = {name: c.type() for name, c in f.channels().items()}
    assert types == dict.fromkeys(CHANNELS, OpenEXR.FLOAT)


def test_exr_channel_data_is_the_layer(tmp_path):
    """Channel 'normal.Y' holds the normal's second component, 'Z' the depth, 'G' the
    beauty's green, row 0 first."""
    layers = random_layers(3, 3, 5)
    path = write_layers(tmp_path / "frame.exr", layers)
    with OpenEXR.File(str(path), separate_channels=True) as f:
        channels = {name: c.pixels for name, c in f.channels().items()}
    assert np.array_equal(bits(channels["normal.Y"]), bits(layers["normal"][..., 1]))
    assert np.array_equal(bits(channels["Z"]), bits(layers["depth"]))
    assert np.array_equal(bits(channels["G"]), bits(layers["beauty"][..., 1]))
    assert np.array_equal(bits(channels["position.X"]), bits(layers["position"][..., 0]))


def test_multilayer_exr_beauty_is_the_default_layer(tmp_path):
    """A reader of plain RGB EXRs (tracer.io.images) sees the beauty."""
    layers = random_layers(4, 3, 4)
    back = read_image(write_layers(tmp_path / "frame.exr", layers))
    assert np.array_equal(bits(back), bits(layers["beauty"]))


def test_plain_exr_reads_as_beauty(tmp_path):
    """An EXR from images.write_image (R, G, B) reads as a beauty-only frame with its
    metadata."""
    rgb = random_layers(5, 4, 6, names=("beauty",))["beauty"]
    back, metadata = read_layers(write_image(tmp_path / "plain.exr", rgb, METADATA))
    assert list(back) == ["beauty"]
    assert np.array_equal(bits(back["beauty"]), bits(rgb))
    assert metadata == METADATA


def test_npz_bundle_members(tmp_path):
    """The bundle holds one array per layer and the metadata JSON as a 0-d string array,
    readable without pickle."""
    path = write_layers(tmp_path / "frame.npz", random_layers(6, 2, 2), METADATA)
    with np.load(path, allow_pickle=False) as bundle:
        assert sorted(bundle.files) == sorted([*LAYERS, "metadata"])
        assert bundle["metadata"].shape == () and bundle["metadata"].dtype.kind == "U"
        assert json.loads(bundle["metadata"].item()) == METADATA
        assert bundle["depth"].shape == (2, 2) and bundle["normal"].shape == (2, 2, 3)


def test_uppercase_suffix_and_other_dtypes(tmp_path):
    """The format follows the extension case-insensitively; float64 input is stored as
    float32."""
    layers = {"beauty": np.linspace(0, 1, 12).reshape(2, 2, 3), "depth": np.ones((2, 2))}
    for name in ("F.EXR", "F.NPZ"):
        back, _ = read_layers(write_layers(tmp_path / name, layers))
        assert back["beauty"].dtype == np.float32
        assert np.array_equal(back["beauty"], layers["beauty"].astype(np.float32))


def beauty(height=4, width=4):
    return np.zeros((height, width, 3), np.float32)


@pytest.mark.parametrize(
    ("layers", "message"),
    [
        ({}, "no 'beauty' layer"),
        ({"albedo": beauty()}, r"no 'beauty' layer \(got albedo\)"),
        (
            {"beauty": beauty(), "diffuse": beauty()},
            r"unknown layer 'diffuse'; the layers are beauty, denoised, albedo, normal, depth, "
            "position",
        ),
        ({"beauty": beauty(), "coverage": beauty()[..., 0]}, "unknown layer 'coverage'"),
        (
            {"beauty": beauty(), "albedo": beauty(3, 4)},
            r"layer 'albedo' is 3x4 \(H x W\), beauty is 4x4",
        ),
        ({"beauty": beauty(), "depth": np.zeros((4, 5))}, "layer 'depth' is 4x5"),
        ({"beauty": beauty()[..., :2]}, r"'beauty': expected shape \(H, W, 3\), got \(4, 4, 2\)"),
        ({"beauty": beauty()[..., 0]}, r"'beauty': expected shape \(H, W, 3\), got \(4, 4\)"),
        ({"beauty": beauty(), "normal": np.zeros((4, 4, 4))}, r"'normal': expected shape"),
        ({"beauty": beauty(), "depth": np.zeros((4, 4, 1))}, r"'depth': expected shape \(H, W\)"),
        ({"beauty": beauty(), "depth": beauty()}, r"'depth': expected shape \(H, W\), got"),
        ({"beauty": beauty(0, 4)}, "empty image"),
    ],
    ids=lambda v: None if isinstance(v, str) else ",".join(v) or "none",
)
@pytest.mark.parametrize("suffix", LAYER_FORMATS)
def test_bad_layers_write_nothing(tmp_path, suffix, layers, message):
    """A frame that breaks the layer contract is refused with what is wrong, and nothing is
    written."""
    with pytest.raises(ValueError, match=message):
        check_layers(layers)
    with pytest.raises(ValueError, match=message):
        write_layers(tmp_path / f"frame{suffix}", layers)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["frame.png", "frame.npy", "frame", "frame.exr.tmp"])
def test_unknown_suffix(tmp_path, name):
    """Other extensions raise ValueError naming the layers formats, on write and on read."""
    with pytest.raises(ValueError, match=r"unknown layers format .*; use one of \.exr, \.npz"):
        write_layers(tmp_path / name, {"beauty": beauty()})
    assert list(tmp_path.iterdir()) == []
    (tmp_path / name).write_bytes(b"")
    with pytest.raises(ValueError, match=r"use one of \.exr, \.npz"):
        read_layers(tmp_path / name)


def test_directory_is_not_an_output(tmp_path):
    (tmp_path / "frame.exr").mkdir()
    with pytest.raises(ValueError, match="directory"):
        write_layers(tmp_path / "frame.exr", {"beauty": beauty()})


def test_exr_with_part_of_a_layer_is_refused(tmp_path):
    """An EXR with some of a layer's channels (normal.X without Y and Z) is a clear error;
    channels that name no layer (foo) are ignored."""
    plane = np.zeros((2, 2), np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    path = str(tmp_path / "odd.exr")
    OpenEXR.File(header, {"R": plane, "G": plane, "B": plane, "foo": plane + 1}).write(path)
    back, metadata = read_layers(path)
    assert list(back) == ["beauty"] and metadata == {}
    OpenEXR.File(header, {"R": plane, "G": plane, "B": plane, "normal.X": plane}).write(path)
    with pytest.raises(ValueError, match=r"layer 'normal' has no normal\.Y, normal\.Z channel"):
        read_layers(path)
    OpenEXR.File(header, {"Y": plane}).write(path)
    with pytest.raises(ValueError, match=r"odd\.exr: no 'beauty' layer"):
        read_layers(path)


def test_npz_with_an_unknown_member_is_refused(tmp_path):
    path = tmp_path / "odd.npz"
    np.savez(path, beauty=beauty(), extra=beauty())
    with pytest.raises(ValueError, match=r"odd\.npz: unknown layer 'extra'"):
        read_layers(path)


class Boom(RuntimeError):
    pass


def failing_after_partial_write(real, target_arg: int):
    """Wrap a writer so it writes its file (argument ``target_arg``, a path or an open file),
    cuts it short, then fails, like a full disk."""

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


@pytest.mark.parametrize("suffix", LAYER_FORMATS)
@pytest.mark.parametrize("existing", [False, True], ids=["new", "existing"])
def test_failed_write_leaves_nothing_behind(tmp_path, monkeypatch, suffix, existing):
    """A write that fails half way leaves no partial file and no temporary file; a file that
    was already there is left untouched."""
    path = tmp_path / f"frame{suffix}"
    if existing:
        write_layers(path, random_layers(7, 3, 4))
        before = path.read_bytes()
    if suffix == ".npz":
        monkeypatch.setattr(np, "savez", failing_after_partial_write(np.savez, 0))
    else:
        monkeypatch.setattr(
            OpenEXR.File, "write", failing_after_partial_write(OpenEXR.File.write, 1)
        )
    with pytest.raises(Boom):
        write_layers(path, random_layers(8, 5, 5), METADATA)
    if existing:
        only_file(tmp_path, path.name)
        assert path.read_bytes() == before
    else:
        assert list(tmp_path.iterdir()) == []


def test_unserialisable_metadata_writes_nothing(tmp_path):
    with pytest.raises(TypeError):
        write_layers(tmp_path / "frame.exr", {"beauty": beauty()}, {"x": object()})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["beauty", "denoised", "albedo", "position"])
def test_colour_and_position_layers_are_as_they_are(name):
    layers = random_layers(9, 3, 2)
    rgb = layer_as_rgb(layers, name)
    assert rgb.dtype == np.float32 and rgb.shape == (3, 2, 3)
    assert np.array_equal(bits(rgb), bits(layers[name]))
    rgb[...] = 0.0  # a copy: the frame's layer is untouched
    assert np.array_equal(bits(layers[name]), bits(random_layers(9, 3, 2)[name]))


def test_normal_is_mapped_to_unit_range():
    """Normals from [-1, 1] to [0, 1]: -1 -> 0, 0 -> 0.5 (no hit), 1 -> 1."""
    normal = np.array([[[-1.0, 0.0, 1.0], [0.6, -0.8, 0.0]]], np.float32)
    rgb = layer_as_rgb({"beauty": beauty(1, 2), "normal": normal}, "normal")
    assert rgb.dtype == np.float32 and rgb.shape == (1, 2, 3)
    assert np.allclose(rgb, [[[0.0, 0.5, 1.0], [0.8, 0.1, 0.5]]], rtol=0, atol=1e-7)


def test_depth_is_normalised_by_its_largest_finite_value():
    """Depth over its largest finite value, in three channels; +inf is 1 and NaN 0."""
    depth = np.array([[0.0, 2.0, 4.0], [np.inf, np.nan, 1.0]], np.float32)
    rgb = layer_as_rgb({"beauty": beauty(2, 3), "depth": depth}, "depth")
    assert rgb.dtype == np.float32 and rgb.shape == (2, 3, 3)
    expected = np.array([[0.0, 0.5, 1.0], [1.0, 0.0, 0.25]], np.float32)
    assert np.array_equal(rgb, np.repeat(expected[..., None], 3, axis=2))
    empty = layer_as_rgb({"beauty": beauty(2, 2), "depth": np.zeros((2, 2))}, "depth")
    assert np.array_equal(empty, np.zeros((2, 2, 3)))


def test_layer_as_rgb_writes_as_an_image(tmp_path):
    """Its output is what images.write_image takes."""
    layers = random_layers(10, 3, 3)
    for name in LAYERS:
        write_image(tmp_path / f"{name}.png", layer_as_rgb(layers, name))
    assert len(list(tmp_path.iterdir())) == len(LAYERS)


@pytest.mark.parametrize("name", ["normal", "diffuse", "R"])
def test_layer_as_rgb_of_a_missing_layer(name):
    """An absent or unknown layer is a ValueError listing the layers present."""
    layers = {"beauty": beauty(), "depth": np.zeros((4, 4), np.float32)}
    with pytest.raises(
        ValueError, match=f"no layer '{name}'; the layers present are beauty, depth"
    ):
        layer_as_rgb(layers, name)


def test_an_id_layer_is_false_colour():
    """Each id its own colour; black where nothing was hit, every other id bright enough to
    tell from it; float formats keep the ids."""
    ids = np.array([[-1.0, 0.0, 1.0, 2.0], [3.0, 1.0, 2**24, -1.0]], np.float32)
    for name in ID_LAYERS:
        layers = {"beauty": beauty(2, 4), name: ids}
        rgb = layer_as_rgb(layers, name)
        assert rgb.dtype == np.float32 and rgb.shape == (2, 4, 3)
        assert not rgb[ids < 0].any() and (rgb[ids >= 0] >= 0.2).all() and (rgb <= 1).all()
        assert np.array_equal(rgb[0, 2], rgb[1, 1])  # id 1 twice
        assert np.array_equal(
            layer_as_rgb(layers, name, view=False), np.repeat(ids[..., None], 3, 2)
        )
    many = layer_as_rgb(
        {"beauty": beauty(1, 256), "object_id": np.arange(256.0)[None]}, "object_id"
    )
    assert len(np.unique(many.reshape(-1, 3), axis=0)) == 256


@pytest.mark.parametrize("suffix", LAYER_FORMATS)
def test_rendered_ids_and_their_names_round_trip(tmp_path, suffix):
    """A render's id layers and the names table of its metadata (tracer.io.metadata.id_names)
    come back from a file: every id present names an object of the scene and its material."""
    data = tiny_scene()
    data["materials"]["blue"] = {"reflectance": [0.1, 0.1, 0.8]}
    data["objects"][1]["material"] = "blue"
    del data["objects"][1]["name"]  # named objects[1]
    state = scene_from_file_model(SceneFile.model_validate(data), SCENES)
    scene = compile_scene(state)
    settings = override(state.render, spp=1, aovs=True)
    camera = override(state.camera, width=24, height=16)
    run = render_pixels(scene, 0, 24 * 16, camera, settings)
    layers, _ = frame_layers(run.rgb.reshape(16, 24, 3), run.aov.reshape(16, 24, -1), settings)
    names = id_names(state, settings)
    path = write_layers(tmp_path / f"frame{suffix}", layers, {"renderer": "tilerender", **names})
    back, metadata = read_layers(path)
    assert metadata["ids"] == names["ids"] == json.loads(json.dumps(names["ids"]))
    assert metadata["ids"]["object_id"] == {"0": "floor", "1": "objects[1]", "2": "lamp"}
    assert metadata["ids"]["material_id"] == {"0": "grey", "1": "lamp", "2": "blue"}
    for name in ID_LAYERS:
        assert np.array_equal(bits(back[name]), bits(layers[name]))
    objects, materials = back["object_id"], back["material_id"]
    assert {-1, 0, 1} <= set(np.unique(objects).tolist())
    for o, m in zip(objects[objects >= 0], materials[objects >= 0], strict=True):
        node = state.nodes[int(o)]
        assert metadata["ids"]["material_id"][str(int(m))] == node.material
    assert np.array_equal(objects < 0, materials < 0)
