"""Scenes: TOML files validated into frozen dataclasses, and the particles they describe."""
from parsph.scene.loader import Scene, load_scene  # noqa: F401  (the public API)
