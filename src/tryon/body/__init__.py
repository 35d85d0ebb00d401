"""Human bodies on the Anny model: shapes from measurements, measurements of shapes,
A-/T-poses, skinning of the body and of other meshes, morphs and motions."""

from tryon.body.anny_model import BodyModel, BodyShape, ShapeParams, body_model

__all__ = ["BodyModel", "BodyShape", "ShapeParams", "body_model"]
