"""tryon: simulation-based virtual try-on."""

__version__ = "0.1.0"
