"""The one exception bad input raises, with a message meant for a person."""


class SceneError(ValueError):
    """A scene, mesh or setting that cannot be rendered; ``str()`` is a one-line explanation."""
