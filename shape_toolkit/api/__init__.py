"""shape_toolkit.api."""
