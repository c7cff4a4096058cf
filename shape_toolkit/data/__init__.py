"""shape_toolkit.data."""
