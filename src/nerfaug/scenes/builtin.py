"""The names of the built-in procedural scenes (`nerfaug.scenes.builders` makes them).

Its own module so that both the package (which re-exports it) and `render` can import it without
importing each other."""

BUILTIN_SCENES = ("lego", "chair", "materials")
