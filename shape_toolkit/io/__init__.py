"""shape_toolkit.io."""
