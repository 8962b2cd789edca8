"""A scene that uses every effect and makes last-bit differences of matrix products show: odd
rotations, non-uniform and mirroring scales, a shearing matrix, static, rigid and deformable
nodes, a parent chain, a texture and a normal map, smooth spheres (shading normals, rigid and
deformable), cards cut out by a mask and blended (alpha), an environment map, spot, point and
sun lights, a thin lens and a camera looking along no axis."""

from pathlib import Path

import numpy as np

from tests.helpers import write_json


def harsh_scene(directory: Path) -> Path:
    """Write the harsh scene (its textures and an environment map with it) to ``directory``."""
    from PIL import Image

    directory.mkdir(parents=True, exist_ok=True)
    texels = (np.indices((8, 8)).sum(axis=0) % 2 * 170 + 40).astype(np.uint8)
    rgb = np.stack([texels, np.rot90(texels), np.full_like(texels, 90)], axis=-1)
    Image.fromarray(rgb, "RGB").save(directory / "checker.png")
    lace = np.dstack([rgb, (np.indices((8, 8)).prod(axis=0) * 37 % 256).astype(np.uint8)])
    Image.fromarray(lace, "RGBA").save(directory / "lace.png")
    rows, cols = np.mgrid[0:32, 0:64].astype(np.float32)
    sky = np.stack([0.2 + rows / 40.0, 0.3 + cols / 100.0, 0.5 + (rows * cols) / 4000.0], -1)
    sky[5:8, 40:44] = [60.0, 50.0, 35.0]  # a small sun painted into the map
    np.save(directory / "sky.npy", sky.astype(np.float32))
    scene = {
        "format": "tilerender/1",
        "camera": {
            "position": [4.37, 2.93, -5.21],
            "look_at": [-0.41, 0.37, 0.83],
            "up": [0.13, 1.0, 0.07],
            "vfov_deg": 41.7,
            "width": 96,
            "height": 64,
            "aperture_radius": 0.031,
            "focus_distance": 6.23,
        },
        "render": {"spp": 4, "max_depth": 7, "rr_depth": 3, "seed": 20261201},
        "sky": {"type": "environment", "file": "sky.npy", "scale": 0.83, "rotation": 23.9},
        "lights": [
            {
                "type": "spot",
                "position": [2.17, 3.31, 1.43],
                "look_at": [-0.53, 0.11, -0.29],
                "intensity": [23.0, 17.5, 9.1],
                "cone_angle_deg": 33.3,
                "falloff_deg": 7.1,
            },
            {"type": "point", "position": [-2.3, 1.9, -1.7], "intensity": [3.1, 4.3, 5.7]},
            {
                "type": "sun",
                "to_sun": [0.31, 0.83, -0.47],
                "irradiance": [2.3, 2.1, 1.9],
                "angular_radius_deg": 2.3,
            },
        ],
        "materials": {
            "checker": {
                "reflectance": [0.9, 0.85, 0.8],
                "texture": {"file": "checker.png"},
                "normal_map": {"file": "checker.png", "strength": 0.3, "scale": [2, 2]},
            },
            "copper": {
                "type": "conductor",
                "eta": [0.27, 0.68, 1.22],
                "k": [3.61, 2.63, 2.29],
                "roughness": 0.31,
            },
            "chrome": {"type": "conductor", "reflectance": [0.9, 0.9, 0.92], "roughness": 0.0},
            "plastic": {
                "type": "plastic",
                "reflectance": [0.1, 0.5, 0.7],
                "ior": 1.47,
                "roughness": 0.17,
            },
            "glass": {"type": "dielectric", "ior": 1.53, "absorption": [0.3, 0.7, 0.1]},
            "mirror": {"type": "mirror", "reflectance": [0.95, 0.93, 0.9]},
            "clay": {"reflectance": [0.6, 0.45, 0.35]},
            "lace": {
                "reflectance": [0.7, 0.3, 0.5],
                "alpha": {"mode": "mask", "cutoff": 0.43, "texture": {"file": "lace.png"}},
            },
            "veil": {"reflectance": [0.3, 0.6, 0.4], "alpha": {"mode": "blend", "value": 0.57}},
            "lamp": {"reflectance": [0, 0, 0], "emission": [7.3, 6.1, 4.7], "two_sided": False},
        },
        "objects": [
            {
                "name": "ground",
                "shape": {"type": "plane", "size": 23.7},
                "material": "checker",
                "transform": {"rotate": [1.7, 17.9, -0.9], "translate": [0.13, -0.02, 0.07]},
            },
            {
                "name": "slab",
                "shape": {"type": "box", "size": [1.3, 0.7, 0.9]},
                "material": "plastic",
                "transform": {
                    "translate": [-1.37, 0.61, 0.29],
                    "rotate": [37.3, -21.7, 11.1],
                    "scale": [0.7, 1.3, 0.45],
                },
            },
            {
                "name": "arm",
                "shape": {"type": "box", "size": [0.3, 1.7, 0.3]},
                "material": "copper",
                "kind": "rigid",
                "transform": {
                    "translate": [0.93, 0.87, -0.61],
                    "rotate": [-12.7, 53.9, 23.3],
                    "scale": [1.1, 0.9, 1.3],
                },
            },
            {
                "name": "hand",
                "parent": "arm",
                "shape": {"type": "sphere", "radius": 0.37, "subdivisions": 1, "smooth": True},
                "material": "glass",
                "kind": "rigid",
                "transform": {
                    "translate": [0.11, 1.03, 0.07],
                    "rotate": [71.3, 0.0, -33.7],
                    "scale": [1.2, 0.8, 1.05],
                },
            },
            {
                "name": "sheared",
                "parent": "arm",
                "shape": {"type": "box", "size": [0.5, 0.5, 0.5]},
                "material": "clay",
                "transform": {
                    "matrix": [
                        [0.83, 0.21, -0.13, -0.71],
                        [0.07, 0.91, 0.17, 0.23],
                        [-0.19, 0.11, 0.77, 0.41],
                        [0.0, 0.0, 0.0, 1.0],
                    ]
                },
            },
            {
                "name": "ball",
                "shape": {"type": "sphere", "radius": 0.53, "subdivisions": 3, "smooth": True},
                "material": "chrome",
                "kind": "deformable",
                "transform": {"translate": [0.37, 0.53, 1.41], "rotate": [13.1, 29.3, 7.7]},
            },
            {
                "name": "mirrored",
                "shape": {"type": "box", "size": [0.6, 0.4, 0.8]},
                "material": "mirror",
                "transform": {
                    "translate": [-0.29, 0.31, -1.93],
                    "rotate": [0.0, -61.3, 0.0],
                    "scale": [-0.9, 1.1, 0.7],
                },
            },
            {
                "name": "lace-card",
                "shape": {"type": "rectangle", "size": [1.1, 0.8]},
                "material": "lace",
                "transform": {"translate": [1.63, 0.71, 0.53], "rotate": [-7.1, 131.3, 3.7]},
            },
            {
                "name": "veil-card",
                "shape": {"type": "rectangle", "size": [0.9, 1.2]},
                "material": "veil",
                "kind": "rigid",
                "transform": {"translate": [-0.47, 0.83, 1.07], "rotate": [4.3, 157.9, -2.9]},
            },
            {
                "name": "lamp",
                "shape": {"type": "rectangle", "size": [0.9, 0.6]},
                "material": "lamp",
                "kind": "rigid",
                "transform": {"translate": [-0.73, 2.71, 0.37], "rotate": [97.3, 12.1, -8.3]},
            },
        ],
    }
    return write_json(directory / "scene.json", scene)
