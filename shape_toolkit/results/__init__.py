"""shape_toolkit.results."""
