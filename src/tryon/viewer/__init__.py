"""The local web viewer (three.js): body, garment, fit-map colouring, orbit controls, frames."""

from tryon.viewer.export import start_server, write_viewer
from tryon.viewer.screenshot import screenshot_viewer

__all__ = ["screenshot_viewer", "start_server", "write_viewer"]
