"""shape_toolkit.features."""
