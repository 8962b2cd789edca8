"""The scene: its file format, model, checks, operations, animation, binary codec and loading."""
