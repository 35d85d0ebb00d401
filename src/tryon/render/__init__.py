"""Offscreen pictures: mesh rendering, colour maps and legends, GIF/MP4 animations."""

from tryon.render.animation import write_gif, write_mp4
from tryon.render.colormap import add_colorbar, scalar_to_rgb
from tryon.render.offscreen import VIEWS, Camera, RenderMesh, opengl_available, render_meshes, save_png

__all__ = [
    "RenderMesh",
    "Camera",
    "VIEWS",
    "render_meshes",
    "save_png",
    "opengl_available",
    "scalar_to_rgb",
    "add_colorbar",
    "write_gif",
    "write_mp4",
]
