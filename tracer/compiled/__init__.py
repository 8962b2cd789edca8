"""A scene compiled to the flat arrays the kernels read."""
