"""What a hit looks like: camera, sampling, Fresnel, microfacets, BSDFs, materials, textures,
lights."""
