"""Image files and visualisations of a render."""
