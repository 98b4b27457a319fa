"""stablelego-jax: differentiable stability analysis of Lego brick layouts."""
from .layout import Layout, LayoutError, Library, default_library, make_layout
from .io import load_layout, parse_json_layout, parse_text_layout, write_layout

__all__ = [
    "Layout",
    "LayoutError",
    "Library",
    "default_library",
    "make_layout",
    "load_layout",
    "parse_json_layout",
    "parse_text_layout",
    "write_layout",
]
