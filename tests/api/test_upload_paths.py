"""The references an upload's meshes make are found as trimesh reads them, and every one must
be a file of the upload (api/upload_paths.py); unit tests on a directory, no service."""

import base64
import json
import struct

import pytest

from api.errors import ApiError
from api.upload_paths import check_references, client_message

PNG = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAIAAACQd1PeAAAADElEQVR4nGP4z8AAAAMBAQDJ/pLvAAAAAElFTkSuQmCC"
)
OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"


def glb(doc: dict) -> bytes:
    """A GLB file holding ``doc`` as its JSON chunk."""
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    chunk = struct.pack("<II", len(text), 0x4E4F534A) + text
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunk)) + chunk


def upload(tmp_path, files: dict[str, bytes | str]):
    """``files`` written under ``tmp_path/files`` (a secret beside it, outside the upload)."""
    (tmp_path / "secret.png").write_bytes(PNG)
    root = tmp_path / "files"
    for name, data in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data.encode() if isinstance(data, str) else data)
    return root


def refused(root, word: str) -> str:
    with pytest.raises(ApiError) as caught:
        check_references(root)
    assert caught.value.status == 422
    assert word in caught.value.message, caught.value.message
    return caught.value.message


@pytest.mark.parametrize(
    "files,word",
    [
        # trimesh reads map_Kd in any case (these were accepted)
        ({"a.obj": "mtllib a.mtl\n" + OBJ, "a.mtl": "newmtl m\nMAP_KD ../secret.png\n"}, ".."),
        ({"a.obj": "mtllib a.mtl\n" + OBJ, "a.mtl": "newmtl m\nmap_kD /etc/x.png\n"}, "absolute"),
        # the material library is read as MTL whatever it is called
        ({"a.obj": "mtllib m.txt\n" + OBJ, "m.txt": "newmtl m\nmap_Kd ../secret.png\n"}, ".."),
        # trimesh finds the first "mtllib" anywhere, tab-separated or joined by a backslash
        ({"a.obj": "mtllib\t../secret.mtl\n" + OBJ}, ".."),
        ({"a.obj": "mtl\\\nlib ../secret.mtl\n" + OBJ}, ".."),
        # GLB JSON chunks are checked like glTF JSON (they were not checked at all)
        ({"a.glb": glb({"buffers": [{"uri": "../secret.bin", "byteLength": 1}]})}, ".."),
        ({"a.glb": glb({"images": [{"uri": "/etc/passwd"}]})}, "absolute"),
        # only base64 data is data to trimesh: any other "data:" URI is a file name
        ({"a.gltf": json.dumps({"buffers": [{"uri": "data:x/../../../secret.png"}]})}, ".."),
        ({"a.gltf": json.dumps({"images": [{"uri": "%2e%2e/secret.png"}]})}, ".."),
        # a PLY header's TextureFile is read by trimesh too
        ({"a.ply": "ply\nformat ascii 1.0\ncomment TextureFile ../secret.png\nend_header\n"}, ".."),
    ],
    ids=[
        "MAP_KD",
        "map_kD absolute",
        "mtllib not .mtl",
        "mtllib tab",
        "mtllib joined",
        "glb buffer",
        "glb image",
        "data uri",
        "percent-encoded",
        "ply texture",
    ],
)
def test_references_trimesh_reads_outside_the_upload_are_refused(tmp_path, files, word):
    refused(upload(tmp_path, files), word)


def test_references_inside_the_upload_pass_as_trimesh_names_them(tmp_path):
    """The rest of the line is one name (spaces kept), and MTL textures are taken from the
    OBJ's directory, where trimesh's resolver looks; base64 URIs read no file."""
    root = upload(
        tmp_path,
        {
            "obj/a.obj": "mtllib materials/my lib.txt\n" + OBJ,
            "obj/materials/my lib.txt": "newmtl m\nKd 1 1 1\nMap_Kd my tex.png\n",
            "obj/my tex.png": PNG,
            "b.glb": glb({"images": [{"uri": "data:image/png;base64,AAAA"}]}),
        },
    )
    check_references(root)
    (root / "obj" / "my tex.png").rename(root / "obj" / "materials" / "my tex.png")
    refused(root, "no such file in the upload")  # not where trimesh looks for it


def test_the_installed_trimesh_refuses_names_that_leave_the_mesh_directory(tmp_path):
    """The resolver behaviour pyproject.toml's trimesh>=5 pin is for (trimesh 4 opened any
    path): a second line of defence behind check_references."""
    from trimesh.resolvers import FilePathResolver

    root = upload(tmp_path, {"a.obj": OBJ})
    with pytest.raises(ValueError, match="escapes"):
        FilePathResolver(str(root / "a.obj")).get("../secret.png")


def test_client_messages_name_no_server_path(tmp_path):
    data = tmp_path / "data"
    files = data / "tmp" / "u1" / "files"
    message = f"{files}/sub/a.obj: cannot read ({files}) near {data}/scenes/s1/state.tls"
    cleaned = client_message(message, data, files)
    assert str(data) not in cleaned and str(tmp_path) not in cleaned
    assert cleaned.startswith("sub/a.obj: cannot read (.) near"), cleaned
