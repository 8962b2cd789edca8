"""The kernels that estimate a pixel, their registry, and the effect plan that configures them."""
