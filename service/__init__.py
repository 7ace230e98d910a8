"""OSLIM: online source likelihood mapping and guided chemical-source search."""

__version__ = "0.1.0"
