"""`tilerender render --aov / --denoise / --layer`: the layers a render writes, in one file or
one at a time, and the errors for layers and combinations that cannot be."""

import numpy as np
import pytest

from tests.cli.test_cli import assert_usage_error, run
from tests.helpers import tiny_scene
from tracer.io.images import read_image, write_image
from tracer.io.layers import LAYERS, layer_as_rgb, read_layers
from tracer.post import denoise as denoise_module

SIZE = ("--width", 24, "--height", 16, "--spp", 2, "-q")


def test_aov_and_denoise_write_every_layer_to_an_exr_and_an_npz(capsys, tmp_path, tiny_scene_file):
    """With --aov --denoise, a .exr and a .npz hold the same layers with the same bits; the
    beauty is the plain render's; the metadata says how the frame was denoised."""
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", tmp_path / "plain.npy", *SIZE)
    assert code == 0, err
    layers = {}
    for suffix in (".exr", ".npz"):
        out = tmp_path / f"frame{suffix}"
        code, _, err = run(
            capsys, "render", tiny_scene_file, "-o", out, *SIZE, "--aov", "--denoise"
        )
        assert code == 0, err
        layers[suffix], metadata = read_layers(out)
        assert metadata["denoise"]["quality"] == "high"
        assert metadata["denoise"]["guides"] == ["albedo", "normal"]
        assert metadata["render"]["aovs"] is True
    names = ["beauty", "denoised", "albedo", "normal", "depth", "position", "alpha"]
    names += ["object_id", "material_id"]
    assert list(layers[".exr"]) == names and list(layers[".npz"]) == names
    for name in names:
        assert np.array_equal(layers[".exr"][name], layers[".npz"][name]), name
    assert np.array_equal(layers[".exr"]["beauty"], read_image(tmp_path / "plain.npy"))
    assert not np.array_equal(layers[".exr"]["denoised"], layers[".exr"]["beauty"])


def test_a_single_layer_image_shows_the_chosen_layer(capsys, tmp_path, tiny_scene_file):
    """A .npy shows the denoised layer by default with --denoise, and --layer picks another;
    a --denoise without --aov still guides the denoiser but keeps no AOV file layer."""
    bundle = tmp_path / "all.npz"
    code, _, err = run(
        capsys, "render", tiny_scene_file, "-o", bundle, *SIZE, "--aov", "--denoise", "fast"
    )
    assert code == 0, err
    layers, _ = read_layers(bundle)
    for layer, expected in [(None, "denoised"), ("albedo", "albedo"), ("depth", "depth")]:
        out = tmp_path / f"{layer}.npy"
        extra = () if layer is None else ("--layer", layer)
        code, _, err = run(
            capsys,
            "render",
            tiny_scene_file,
            "-o",
            out,
            *SIZE,
            "--aov",
            "--denoise",
            "fast",
            *extra,
        )
        assert code == 0, err
        assert np.array_equal(read_image(out), layer_as_rgb(layers, expected, view=False)), layer
    exr = tmp_path / "denoised.exr"
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", exr, *SIZE, "--denoise", "fast")
    assert code == 0, err
    assert list(read_layers(exr)[0]) == ["beauty", "denoised"]
    # Float formats keep a layer's values; a named layer with a .exr is that layer alone.
    depth = tmp_path / "depth.exr"
    code, _, err = run(
        capsys, "render", tiny_scene_file, "-o", depth, *SIZE, "--aov", "--layer", "depth"
    )
    assert code == 0, err
    assert list(read_layers(depth)[0]) == ["beauty"]
    assert np.array_equal(read_image(depth)[..., 0], layers["depth"])
    assert read_image(depth).max() > 1.0


@pytest.mark.parametrize("executor", ["--in-process", "--no-in-process"])
def test_the_id_layers_and_what_they_name(capsys, tmp_path, tiny_scene_file, executor):
    """--aov writes the object and material ids with the names they stand for in the metadata
    (in process and through Ray); --layer shows one: its ids in a .npy, false colour in a .png,
    each object's material where it shows."""
    bundle = tmp_path / "all.npz"
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", bundle, *SIZE, "--aov", executor)
    assert code == 0, err
    layers, metadata = read_layers(bundle)
    objects = {"0": "floor", "1": "cube", "2": "lamp"}
    assert metadata["ids"] == {"object_id": objects, "material_id": {"0": "grey", "1": "lamp"}}
    materials = {o["name"]: o["material"] for o in tiny_scene()["objects"]}
    seen = layers["object_id"] >= 0
    assert {0, 1} <= set(np.unique(layers["object_id"]).tolist())
    for o, m in zip(layers["object_id"][seen], layers["material_id"][seen], strict=True):
        assert metadata["ids"]["material_id"][str(int(m))] == materials[objects[str(int(o))]]
    for layer in ("object_id", "material_id"):
        for suffix in (".npy", ".png"):
            out = tmp_path / f"{layer}{suffix}"
            code, _, err = run(
                capsys, "render", tiny_scene_file, "-o", out, *SIZE, "--aov", "--layer", layer
            )
            assert code == 0, err
            shown = layer_as_rgb(layers, layer, view=suffix == ".png")
            expected = read_image(write_image(tmp_path / f"expected{suffix}", shown))
            assert np.array_equal(read_image(out), expected), (layer, suffix)


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (("--layer", "albedo"), ("--layer albedo", "beauty", "--aov adds")),
        (("--layer", "denoised", "--aov"), ("--layer denoised", "--denoise")),
        (("--aov", "--integrator", "ao"), ("ao integrator gives no AOVs",)),
        (("--denoise", "--kernel", "stream"), ("stream kernel does not record AOVs",)),
        (("--denoise", "best"), ("invalid choice: 'best'",)),
        (("--layer", "shadow"), ("invalid choice: 'shadow'",)),
    ],
)
def test_impossible_layers_are_usage_errors(capsys, tmp_path, tiny_scene_file, extra, words):
    """A layer the render will not have, AOVs where no paths give them, and unknown names end
    with exit code 2 and the reason, before anything is written."""
    out = tmp_path / "x.png"
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, *SIZE, *extra)
    assert_usage_error(code, err, *words)
    assert not out.exists()


def test_a_missing_denoiser_fails_the_command_with_a_message(
    capsys, tmp_path, monkeypatch, tiny_scene_file
):
    """Without pyoidn, --denoise ends with a one-line message naming the package, not a
    traceback, and writes nothing."""

    def unavailable():
        raise denoise_module.DenoiserUnavailable("denoising needs the pyoidn package")

    monkeypatch.setattr(denoise_module, "_load_pyoidn", unavailable)
    out = tmp_path / "x.png"
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, *SIZE, "--denoise")
    assert code != 0 and "pyoidn" in err and "Traceback" not in err
    assert not out.exists()


def test_no_aov_and_denoise_off_override_the_scene(capsys, tmp_path):
    """A scene that asks for AOVs and denoising gets them by default; --no-aov --denoise off
    render its beauty alone."""
    from tests.helpers import tiny_scene, write_json

    data = tiny_scene()
    data["render"].update(aovs=True, denoise="fast")
    scene = write_json(tmp_path / "scene.json", data)
    for extra, names in [((), len(LAYERS)), (("--no-aov", "--denoise", "off"), 1)]:
        out = tmp_path / f"{len(extra)}.exr"
        code, _, err = run(capsys, "render", scene, "-o", out, *SIZE, *extra)
        assert code == 0, err
        assert len(read_layers(out)[0]) == names


def test_the_guides_are_prefiltered_where_they_are_noisy(capsys, tmp_path, tiny_scene_file):
    """--denoise-prefilter auto (the default) takes an untextured pinhole scene's guides as they
    are, on prefilters them; the metadata says which, and only the denoised layer changes."""
    denoised = {}
    for choice in ("auto", "on", "off"):
        out = tmp_path / f"{choice}.npz"
        code, _, err = run(
            capsys,
            "render",
            tiny_scene_file,
            "-o",
            out,
            *SIZE,
            "--denoise",
            "fast",
            "--denoise-prefilter",
            choice,
        )
        assert code == 0, err
        layers, metadata = read_layers(out)
        assert metadata["denoise"]["prefiltered"] is (choice == "on"), choice
        assert metadata["render"]["denoise_prefilter"] == ("off" if choice == "auto" else choice)
        denoised[choice] = layers["denoised"]
    assert np.array_equal(denoised["auto"], denoised["off"])
    assert not np.array_equal(denoised["on"], denoised["off"])


def test_a_target_error_with_denoising_says_what_it_estimates(capsys, tmp_path, tiny_scene_file):
    """--target-error with --denoise renders in waves and says plainly which image's error
    decides: at these few samples, the beauty's."""
    out = tmp_path / "frame.npz"
    code, _, err = run(
        capsys,
        "render",
        tiny_scene_file,
        "-o",
        out,
        "--width",
        24,
        "--height",
        16,
        "--target-error",
        0.5,
        "--max-spp",
        8,
        "--denoise",
        "fast",
    )
    assert code == 0, err
    assert "before that, the beauty's estimate decides" in " ".join(err.split())
    layers, metadata = read_layers(out)
    assert "denoised" in layers and metadata["progressive"]["stopped"] in (
        "target_error",
        "max_spp",
    )
    assert metadata["progressive"]["error_of"] == "beauty"
