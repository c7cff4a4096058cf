"""shape_toolkit.core."""
