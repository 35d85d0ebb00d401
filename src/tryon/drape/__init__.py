"""The physics draper: a garment of a size and fabric on a body from measurements."""

from tryon.drape.pipeline import DrapeRequest, DrapeResult, drape

__all__ = ["DrapeRequest", "DrapeResult", "drape"]
