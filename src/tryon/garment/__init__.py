"""Garments from sewing patterns: the pattern model, parametric drafts in standard and
made-to-measure sizes and triangulation with matched seams (dressing a body with them is
the drape stage's: `tryon.drape.dress`)."""

from tryon.garment.drafts import GARMENTS, Ease, draft
from tryon.garment.pattern import Edge, Panel, Pattern, PatternError, Seam
from tryon.garment.sizes import SIZES, size_measurements

__all__ = ["GARMENTS", "SIZES", "Ease", "Edge", "Panel", "Pattern", "PatternError", "Seam", "draft", "size_measurements"]
