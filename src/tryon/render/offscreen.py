"""Offscreen rendering of triangle meshes to RGB images.

Main path: OpenGL through moderngl on a headless EGL context (Mesa llvmpipe works),
4x MSAA. The context is created lazily once per process and reused. When no OpenGL
context can be created, a numba z-buffer rasteriser with 2x2 supersampling and the
same shading takes over (one warning is logged).

Conventions (the project's Anny frame: Z up, metres). :meth:`Camera.fit` views are
named for a body facing -Y: ``front`` puts the camera on the -Y side looking along
+Y, ``back`` on +Y, ``side`` on +X looking along -X, ``top`` above looking down (image
up = +Y), ``three_quarter`` between front and side, slightly above. Any other
direction is available through ``azimuth_deg`` (from the front, towards +X) and
``elevation_deg``.

Shading: colours are sRGB; lighting is computed in linear light: a hemisphere ambient
(brighter from +Z), a key and a fill directional light fixed relative to the camera
(key from the upper left), Lambert diffuse plus a little Blinn-Phong specular. Two-sided
meshes (cloth) flip the normal of back-facing fragments so both sides are lit.
"""

from __future__ import annotations

import logging
import math
import os
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from tryon.errors import InputFileError, MeshError, TryonError
from tryon.io.atomic import atomic_write

__all__ = ["RenderMesh", "Camera", "render_meshes", "save_png", "opengl_available", "VIEWS"]

log = logging.getLogger(__name__)

# name -> (azimuth from the front towards +X, elevation), degrees
VIEWS: dict[str, tuple[float, float]] = {
    "front": (0.0, 0.0),
    "back": (180.0, 0.0),
    "side": (90.0, 0.0),
    "top": (0.0, 90.0),
    "three_quarter": (40.0, 15.0),
}

# Lights in camera coordinates (x right, y up, z towards the viewer), unit vectors towards the light.
_KEY_DIR_CAM = np.array([-0.45, 0.55, 0.70])
_FILL_DIR_CAM = np.array([0.65, -0.15, 0.74])
_SHADING = {
    "sky": 0.22,  # ambient for normals pointing +Z
    "ground": 0.10,  # ambient for normals pointing -Z
    "key": 0.80,
    "fill": 0.28,
    "spec": 0.10,
    "shininess": 40.0,
}
_GAMMA = 2.2
_WIRE_COLOR = (0.12, 0.12, 0.14)


# ----------------------------------------------------------------------------- inputs


def _as_numpy(x: Any, dtype: Any = None) -> np.ndarray:
    if hasattr(x, "detach"):  # torch tensor
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=dtype)


def _unit_colors(c: Any, rows: int | None, what: str) -> np.ndarray:
    """Colours to float 0..1: floats pass through (clipped), uint8 are divided by 255."""
    arr = _as_numpy(c)
    if np.issubdtype(arr.dtype, np.integer):
        arr = arr.astype(np.float64) / 255.0
    arr = arr.astype(np.float64)
    if rows is None:
        shape_ok = arr.shape == (3,)
    else:
        shape_ok = arr.ndim == 2 and arr.shape[0] == rows and arr.shape[1] in (3, 4)
    if not shape_ok or not np.isfinite(arr).all():
        want = "an RGB triple" if rows is None else f"a finite [{rows}, 3] array"
        raise MeshError(f"render: {what} must be {want}, got shape {arr.shape}")
    return np.clip(arr[..., :3], 0.0, 1.0)


@dataclass
class RenderMesh:
    """A triangle mesh to draw. Colours are sRGB, floats in 0..1 (or uint8 arrays).

    Give at most one of ``vertex_colors [N,3]`` and ``face_colors [F,3]``; otherwise
    the uniform ``color`` is used. ``two_sided`` lights both sides (cloth); ``smooth``
    interpolates area-weighted vertex normals, else each face is flat; ``wireframe``
    draws the edges over the surface.
    """

    vertices: Any
    faces: Any
    color: tuple[float, float, float] = (0.72, 0.72, 0.75)
    vertex_colors: Any = None
    face_colors: Any = None
    two_sided: bool = True
    smooth: bool = True
    wireframe: bool = False
    vertex_normals: Any = None   # [N,3]: smooth shading with these instead of the faces' own

    def __post_init__(self) -> None:
        self.vertices = _as_numpy(self.vertices, np.float64)
        faces = _as_numpy(self.faces)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise MeshError(f"render: vertices must be [N, 3], got shape {self.vertices.shape}")
        if not np.isfinite(self.vertices).all():
            raise MeshError("render: vertices contain NaN or inf; check the simulation output")
        if faces.ndim != 2 or faces.shape[1] != 3 or (faces.size and not np.issubdtype(faces.dtype, np.integer)):
            raise MeshError(f"render: faces must be an integer [F, 3] array, got {faces.dtype} {faces.shape}")
        self.faces = faces.astype(np.int64)
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise MeshError(f"render: face indices must lie in [0, {len(self.vertices)})")
        if self.vertex_normals is not None and np.shape(self.vertex_normals) != self.vertices.shape:
            raise MeshError(f"render: vertex_normals must be [N, 3] like the vertices, got {np.shape(self.vertex_normals)}")
        if self.vertex_colors is not None and self.face_colors is not None:
            raise MeshError("render: give vertex_colors or face_colors, not both")
        self.color = tuple(_unit_colors(self.color, None, "color"))
        if self.vertex_colors is not None:
            self.vertex_colors = _unit_colors(self.vertex_colors, len(self.vertices), "vertex_colors")
        if self.face_colors is not None:
            self.face_colors = _unit_colors(self.face_colors, len(self.faces), "face_colors")

    def corner_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-corner positions, normals and colours, each ``[F, 3, 3]``."""
        pos = self.vertices[self.faces]
        face_n = np.cross(pos[:, 1] - pos[:, 0], pos[:, 2] - pos[:, 0])  # length = 2 * area
        if self.smooth and self.vertex_normals is not None:
            normals = _normalized(_as_numpy(self.vertex_normals, np.float64).reshape(-1, 3))[self.faces]
        elif self.smooth:
            vn = np.zeros_like(self.vertices)
            for k in range(3):
                for axis in range(3):
                    vn[:, axis] += np.bincount(self.faces[:, k], face_n[:, axis], minlength=len(vn))
            normals = _normalized(vn)[self.faces]
        else:
            normals = np.repeat(_normalized(face_n)[:, None, :], 3, axis=1)
        if self.vertex_colors is not None:
            colors = self.vertex_colors[self.faces]
        elif self.face_colors is not None:
            colors = np.repeat(self.face_colors[:, None, :], 3, axis=1)
        else:
            colors = np.broadcast_to(np.asarray(self.color), pos.shape).copy()
        return pos, normals, colors

    def edges(self) -> np.ndarray:
        """Unique undirected edges ``[E, 2]``."""
        e = np.concatenate([self.faces[:, [0, 1]], self.faces[:, [1, 2]], self.faces[:, [2, 0]]])
        return np.unique(np.sort(e, axis=1), axis=0)


def _normalized(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    out = np.divide(v, n, out=np.zeros_like(v), where=n > 1e-300)
    out[(n[..., 0] <= 1e-300)] = (0.0, 0.0, 1.0)
    return out


# ----------------------------------------------------------------------------- camera


def _vertices_of(item: Any) -> np.ndarray:
    return item.vertices if isinstance(item, RenderMesh) else _as_numpy(item, np.float64).reshape(-1, 3)


@dataclass
class Camera:
    """Pinhole camera: ``eye`` looks at ``target``; ``up`` (default +Z) fixes the roll.

    ``fov_deg`` is the vertical field of view. ``near``/``far`` default to planes that
    enclose the rendered meshes.
    """

    eye: Any
    target: Any = (0.0, 0.0, 0.0)
    up: Any = (0.0, 0.0, 1.0)
    fov_deg: float = 30.0
    near: float | None = None
    far: float | None = None

    def __post_init__(self) -> None:
        self.eye = np.asarray(self.eye, dtype=np.float64).reshape(3)
        self.target = np.asarray(self.target, dtype=np.float64).reshape(3)
        self.up = np.asarray(self.up, dtype=np.float64).reshape(3)
        if not (0.0 < self.fov_deg < 179.0):
            raise TryonError(f"camera fov_deg must be in (0, 179), got {self.fov_deg}")
        if np.linalg.norm(self.target - self.eye) < 1e-12:
            raise TryonError("camera eye and target coincide; move the eye away from the target")

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) unit vectors in world coordinates."""
        forward = self.target - self.eye
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, self.up)
        if np.linalg.norm(right) < 1e-9:  # up parallel to the view: pick any perpendicular
            right = np.cross(forward, [1.0, 0.0, 0.0] if abs(forward[0]) < 0.9 else [0.0, 1.0, 0.0])
        right = right / np.linalg.norm(right)
        return right, np.cross(right, forward), forward

    def view_matrix(self) -> np.ndarray:
        """World -> camera (OpenGL convention: camera looks along -z)."""
        right, up, forward = self.basis()
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = right, up, -forward
        m[:3, 3] = -m[:3, :3] @ self.eye
        return m

    def projection_matrix(self, aspect: float, near: float, far: float) -> np.ndarray:
        """OpenGL perspective projection (clip space, NDC depth in [-1, 1])."""
        f = 1.0 / math.tan(math.radians(self.fov_deg) / 2.0)
        m = np.zeros((4, 4))
        m[0, 0], m[1, 1] = f / aspect, f
        m[2, 2], m[2, 3] = (far + near) / (near - far), 2.0 * far * near / (near - far)
        m[3, 2] = -1.0
        return m

    def project(self, points: Any, width: int, height: int) -> np.ndarray:
        """Pixel coordinates [N,2] (x right, y down, pixel centres at +0.5) of world points
        in a ``width`` x ``height`` image of this camera."""
        right, up, forward = self.basis()
        d = np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.eye
        depth = np.maximum(d @ forward, 1e-9)
        f = 0.5 * height / math.tan(math.radians(self.fov_deg) / 2.0)
        return np.stack([0.5 * width + f * (d @ right) / depth, 0.5 * height - f * (d @ up) / depth], 1)

    def clip_planes(self, points: np.ndarray) -> tuple[float, float]:
        """``(near, far)``: the fixed values if set, else planes around ``points``."""
        _, _, forward = self.basis()
        depth = (points - self.eye) @ forward if len(points) else np.array([1.0])
        far = self.far if self.far is not None else max(float(depth.max()) * 1.05, 1e-3)
        near = self.near if self.near is not None else max(float(depth.min()) * 0.95, far * 1e-4)
        return near, far

    @classmethod
    def fit(
        cls,
        meshes: Sequence[Any],
        view: str = "front",
        margin: float = 1.1,
        fov_deg: float = 30.0,
        aspect: float = 1.0,
        azimuth_deg: float | None = None,
        elevation_deg: float | None = None,
    ) -> Camera:
        """Camera that frames the union bounding box of ``meshes`` (RenderMesh or [N,3] arrays).

        ``view`` is one of :data:`VIEWS` (see the module docstring for the convention);
        ``azimuth_deg``/``elevation_deg`` override its angles. ``margin`` > 1 leaves
        that much spare room around the box; ``aspect`` is the image width / height.
        """
        if view not in VIEWS:
            raise TryonError(f"unknown view {view!r}; choose one of {sorted(VIEWS)}")
        pts = np.concatenate([_vertices_of(m) for m in meshes]) if len(meshes) else np.zeros((0, 3))
        if len(pts) == 0:
            raise MeshError("Camera.fit: no vertices to frame")
        az, el = VIEWS[view]
        az = math.radians(az if azimuth_deg is None else azimuth_deg)
        el = math.radians(el if elevation_deg is None else elevation_deg)
        to_eye = np.array([math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)])
        up = np.array([0.0, 0.0, 1.0]) if abs(math.cos(el)) > 1e-6 else np.array([-math.sin(az), math.cos(az), 0.0])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        center = 0.5 * (lo + hi)
        probe = cls(eye=center + to_eye, target=center, up=up, fov_deg=fov_deg)
        distance = _fit_distance(probe, lo, hi, margin, aspect)
        return cls(eye=center + distance * to_eye, target=center, up=up, fov_deg=fov_deg)


def _fit_distance(cam: Camera, lo: np.ndarray, hi: np.ndarray, margin: float, aspect: float) -> float:
    """Smallest eye-to-centre distance at which all 8 box corners lie inside the view (with margin)."""
    right, up, forward = cam.basis()
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    rel = corners - 0.5 * (lo + hi)
    x, y, z = np.abs(rel @ right), np.abs(rel @ up), rel @ forward
    ty = math.tan(math.radians(cam.fov_deg) / 2.0) / margin
    tx = ty * aspect
    need = np.maximum(x / tx, y / ty) - z
    extent = float(np.linalg.norm(hi - lo))
    return max(float(need.max()), float((-z).max()) + 0.05 * extent, 1e-3)


# ----------------------------------------------------------------------------- scene packing


@dataclass
class _Scene:
    """Everything a backend needs, as flat arrays in world coordinates."""

    pos: np.ndarray  # [F, 3, 3] corner positions
    normal: np.ndarray  # [F, 3, 3]
    color: np.ndarray  # [F, 3, 3] sRGB
    two_sided: np.ndarray  # [F] bool
    ranges: list[tuple[int, int, bool]]  # (first face, face count, two_sided) per mesh
    wire: np.ndarray  # [E, 2, 3] edge end points
    mvp: np.ndarray  # [4, 4]
    eye: np.ndarray
    key_dir: np.ndarray
    fill_dir: np.ndarray
    width: int
    height: int
    background: np.ndarray
    lights: dict[str, float] = field(default_factory=lambda: dict(_SHADING))


def _pack_scene(meshes: Sequence[RenderMesh], width: int, height: int, camera: Camera, background: Any) -> _Scene:
    parts = [m.corner_arrays() for m in meshes]
    pos = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3, 3))
    ranges, first = [], 0
    for m in meshes:
        ranges.append((first, len(m.faces), bool(m.two_sided)))
        first += len(m.faces)
    wires = [m.vertices[m.edges()] for m in meshes if m.wireframe]
    all_pts = np.concatenate([m.vertices for m in meshes]) if meshes else np.zeros((0, 3))
    near, far = camera.clip_planes(all_pts)
    mvp = camera.projection_matrix(width / height, near, far) @ camera.view_matrix()
    right, up, forward = camera.basis()
    cam_to_world = np.stack([right, up, -forward], axis=1)
    return _Scene(
        pos=pos,
        normal=np.concatenate([p[1] for p in parts]) if parts else pos.copy(),
        color=np.concatenate([p[2] for p in parts]) if parts else pos.copy(),
        two_sided=np.concatenate([np.full(len(m.faces), bool(m.two_sided)) for m in meshes] or [np.zeros(0, bool)]),
        ranges=ranges,
        wire=np.concatenate(wires) if wires else np.zeros((0, 2, 3)),
        mvp=mvp,
        eye=camera.eye,
        key_dir=_normalized(cam_to_world @ _KEY_DIR_CAM),
        fill_dir=_normalized(cam_to_world @ _FILL_DIR_CAM),
        width=width,
        height=height,
        background=background,
    )


# ----------------------------------------------------------------------------- OpenGL backend

_VERTEX_SHADER = """
#version 330
uniform mat4 mvp;
uniform float depth_bias;
in vec3 in_pos;
in vec3 in_normal;
in vec3 in_color;
out vec3 v_pos;
out vec3 v_normal;
out vec3 v_color;
void main() {
    v_pos = in_pos;
    v_normal = in_normal;
    v_color = in_color;
    gl_Position = mvp * vec4(in_pos, 1.0);
    gl_Position.z -= depth_bias * gl_Position.w;
}
"""

_FRAGMENT_SHADER = """
#version 330
uniform vec3 eye;
uniform vec3 key_dir;
uniform vec3 fill_dir;
uniform float sky;
uniform float ground;
uniform float key;
uniform float fill;
uniform float spec;
uniform float shininess;
uniform float gamma;
uniform bool two_sided;
uniform bool unlit;
in vec3 v_pos;
in vec3 v_normal;
in vec3 v_color;
out vec4 f_color;
void main() {
    if (unlit) { f_color = vec4(v_color, 1.0); return; }
    vec3 n = normalize(v_normal);
    if (two_sided && !gl_FrontFacing) n = -n;
    vec3 view = normalize(eye - v_pos);
    vec3 albedo = pow(v_color, vec3(gamma));
    float ambient = mix(ground, sky, 0.5 + 0.5 * n.z);
    float diffuse = ambient + key * max(dot(n, key_dir), 0.0) + fill * max(dot(n, fill_dir), 0.0);
    float highlight = (dot(n, key_dir) > 0.0)
        ? spec * pow(max(dot(n, normalize(key_dir + view)), 0.0), shininess) : 0.0;
    vec3 lit = albedo * diffuse + vec3(highlight);
    f_color = vec4(pow(clamp(lit, 0.0, 1.0), vec3(1.0 / gamma)), 1.0);
}
"""


class _GLState:
    """The process-wide moderngl context and shader program (created once, lazily)."""

    def __init__(self) -> None:
        import moderngl

        try:
            self.ctx = moderngl.create_standalone_context(backend="egl")
        except Exception as egl_exc:  # noqa: BLE001 - any driver failure means "try the next option"
            try:
                self.ctx = moderngl.create_standalone_context()
            except Exception:  # noqa: BLE001
                raise egl_exc from None
        self.program = self.ctx.program(vertex_shader=_VERTEX_SHADER, fragment_shader=_FRAGMENT_SHADER)
        self.samples = min(4, int(self.ctx.max_samples))
        self.pid = os.getpid()


# An OpenGL context is current in one thread only, so each thread gets its own (created
# on first use, then reused); a forked child process creates a fresh one.
_THREAD = threading.local()
_GL_FAILURE: str | None = None
_LOCK = threading.Lock()


def _gl_state() -> _GLState | None:
    """This thread's context, or None (with one warning per process) if OpenGL is unavailable."""
    global _GL_FAILURE
    state: _GLState | None = getattr(_THREAD, "gl", None)
    if state is not None and state.pid == os.getpid():
        return state
    if _GL_FAILURE is not None:
        return None
    try:
        state = _GLState()
    except Exception as exc:  # noqa: BLE001 - missing libEGL, no driver, ...
        with _LOCK:
            if _GL_FAILURE is None:
                _GL_FAILURE = f"{type(exc).__name__}: {exc}".splitlines()[0]
                log.warning("OpenGL offscreen context unavailable (%s); using the numpy rasteriser", _GL_FAILURE)
        return None
    _THREAD.gl = state
    return state


def opengl_available() -> bool:
    """True when an offscreen OpenGL context can be (or has been) created in this thread."""
    return _gl_state() is not None


def _set_uniforms(prog: Any, scene: _Scene) -> None:
    prog["mvp"].write(scene.mvp.T.astype("f4").tobytes())  # GLSL matrices are column-major
    prog["eye"].value = tuple(scene.eye)
    prog["key_dir"].value = tuple(scene.key_dir)
    prog["fill_dir"].value = tuple(scene.fill_dir)
    for name, value in scene.lights.items():
        prog[name].value = value
    prog["gamma"].value = _GAMMA


def _render_gl(gl: _GLState, scene: _Scene) -> np.ndarray:
    ctx, prog = gl.ctx, gl.program
    size = (scene.width, scene.height)
    tri = np.concatenate([scene.pos, scene.normal, scene.color], axis=2).astype("f4")  # [F, 3, 9]
    wire = scene.wire.reshape(-1, 3)
    lines = np.concatenate([wire, np.zeros_like(wire), np.broadcast_to(_WIRE_COLOR, wire.shape)], axis=1).astype("f4")
    resources: list[Any] = []
    try:
        color_rb = ctx.renderbuffer(size, 4, samples=gl.samples)
        depth_rb = ctx.depth_renderbuffer(size, samples=gl.samples)
        msaa = ctx.framebuffer(color_attachments=[color_rb], depth_attachment=depth_rb)
        resolve_rb = ctx.renderbuffer(size, 4)
        resolve = ctx.framebuffer(color_attachments=[resolve_rb])
        resources += [color_rb, depth_rb, msaa, resolve_rb, resolve]
        msaa.use()
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE)
        bg = tuple(float(c) for c in scene.background)
        msaa.clear(*bg, 1.0, depth=1.0)
        _set_uniforms(prog, scene)
        prog["unlit"].value = False
        prog["depth_bias"].value = 0.0
        if len(tri):
            vbo = ctx.buffer(tri.tobytes())
            vao = ctx.vertex_array(prog, [(vbo, "3f 3f 3f", "in_pos", "in_normal", "in_color")])
            resources += [vbo, vao]
            for first, count, two_sided in scene.ranges:
                prog["two_sided"].value = two_sided
                vao.render(mode=ctx.TRIANGLES, vertices=3 * count, first=3 * first)
        if len(lines):
            prog["unlit"].value = True
            prog["depth_bias"].value = _WIRE_DEPTH_BIAS
            lvbo = ctx.buffer(np.ascontiguousarray(lines).tobytes())
            lvao = ctx.vertex_array(prog, [(lvbo, "3f 3f 3f", "in_pos", "in_normal", "in_color")])
            resources += [lvbo, lvao]
            lvao.render(mode=ctx.LINES)
        ctx.copy_framebuffer(dst=resolve, src=msaa)
        raw = resolve.read(components=3, alignment=1)
    finally:
        for r in reversed(resources):
            r.release()
    return np.frombuffer(raw, dtype=np.uint8).reshape(scene.height, scene.width, 3)[::-1].copy()


_WIRE_DEPTH_BIAS = 2e-4  # NDC units: lines win the depth test against their own faces


# ----------------------------------------------------------------------------- numpy / numba backend

_SUPERSAMPLE = 2  # 2x2 samples per pixel, comparable to 4x MSAA


@njit(cache=True)
def _rasterize_kernel(
    sx: np.ndarray, sy: np.ndarray, sz: np.ndarray, invw: np.ndarray,
    depth: np.ndarray, tri_id: np.ndarray, bary: np.ndarray,
) -> None:  # fmt: skip
    """Z-buffer triangles given per-corner screen coordinates ``[F, 3]`` (pixels, y down).

    Pixel centres at +0.5; screen-space barycentrics decide coverage and depth, and are
    made perspective-correct (weighted by 1/w) for attribute interpolation.
    """
    height, width = depth.shape
    for t in range(sx.shape[0]):
        x0, x1, x2 = sx[t, 0], sx[t, 1], sx[t, 2]
        y0, y1, y2 = sy[t, 0], sy[t, 1], sy[t, 2]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        xmin = max(int(math.floor(min(x0, min(x1, x2)) - 0.5)), 0)
        xmax = min(int(math.ceil(max(x0, max(x1, x2)) - 0.5)), width - 1)
        ymin = max(int(math.floor(min(y0, min(y1, y2)) - 0.5)), 0)
        ymax = min(int(math.ceil(max(y0, max(y1, y2)) - 0.5)), height - 1)
        inv_area = 1.0 / area
        for py in range(ymin, ymax + 1):
            cy = py + 0.5
            for px in range(xmin, xmax + 1):
                cx = px + 0.5
                b0 = ((x1 - cx) * (y2 - cy) - (x2 - cx) * (y1 - cy)) * inv_area
                b1 = ((x2 - cx) * (y0 - cy) - (x0 - cx) * (y2 - cy)) * inv_area
                b2 = 1.0 - b0 - b1
                if b0 < 0.0 or b1 < 0.0 or b2 < 0.0:
                    continue
                z = b0 * sz[t, 0] + b1 * sz[t, 1] + b2 * sz[t, 2]
                if z < -1.0 or z > 1.0 or z >= depth[py, px]:
                    continue
                depth[py, px] = z
                tri_id[py, px] = t
                p0, p1, p2 = b0 * invw[t, 0], b1 * invw[t, 1], b2 * invw[t, 2]
                s = p0 + p1 + p2
                bary[py, px, 0] = p0 / s
                bary[py, px, 1] = p1 / s
                bary[py, px, 2] = p2 / s


@njit(cache=True)
def _wire_kernel(
    sx: np.ndarray, sy: np.ndarray, sz: np.ndarray, bias: float, thickness: int, depth: np.ndarray, hit: np.ndarray
) -> None:
    """Mark ``thickness``-pixel dots along edge segments ``[E, 2]`` (screen coordinates) that pass the depth test."""
    height, width = depth.shape
    for e in range(sx.shape[0]):
        length = max(abs(sx[e, 1] - sx[e, 0]), abs(sy[e, 1] - sy[e, 0]))
        steps = int(math.ceil(length)) + 1
        for i in range(steps + 1):
            t = i / steps
            x = sx[e, 0] + t * (sx[e, 1] - sx[e, 0])
            y = sy[e, 0] + t * (sy[e, 1] - sy[e, 0])
            z = sz[e, 0] + t * (sz[e, 1] - sz[e, 0]) - bias
            for dy in range(thickness):
                py = int(math.floor(y)) + dy
                for dx in range(thickness):
                    px = int(math.floor(x)) + dx
                    if 0 <= px < width and 0 <= py < height and -1.0 <= z <= depth[py, px]:
                        hit[py, px] = True


def _to_screen(points: np.ndarray, mvp: np.ndarray, width: int, height: int) -> tuple[np.ndarray, ...]:
    """World points ``[..., 3]`` -> (x pixels, y pixels down, NDC z, 1/w, w)."""
    clip = points @ mvp[:3, :3].T + mvp[:3, 3]
    w = points @ mvp[3, :3] + mvp[3, 3]
    safe_w = np.where(np.abs(w) > 1e-12, w, 1e-12)
    ndc = clip / safe_w[..., None]
    sx = (ndc[..., 0] + 1.0) * 0.5 * width
    sy = (1.0 - ndc[..., 1]) * 0.5 * height
    return sx, sy, ndc[..., 2], 1.0 / safe_w, w


def _shade(scene: _Scene, normal: np.ndarray, pos: np.ndarray, color: np.ndarray) -> np.ndarray:
    """The fragment shader's lighting, vectorised over pixels (normals already facing-corrected)."""
    li = scene.lights
    n = _normalized(normal)
    view = _normalized(scene.eye - pos)
    albedo = color**_GAMMA
    ambient = li["ground"] + (li["sky"] - li["ground"]) * (0.5 + 0.5 * n[:, 2])
    key_dot = n @ scene.key_dir
    diffuse = ambient + li["key"] * np.maximum(key_dot, 0.0) + li["fill"] * np.maximum(n @ scene.fill_dir, 0.0)
    half = _normalized(scene.key_dir + view)
    spec_dot = np.maximum(np.einsum("ij,ij->i", n, half), 0.0)
    highlight = np.where(key_dot > 0.0, li["spec"] * spec_dot ** li["shininess"], 0.0)
    lit = albedo * diffuse[:, None] + highlight[:, None]
    return np.clip(lit, 0.0, 1.0) ** (1.0 / _GAMMA)


def _render_numpy(scene: _Scene) -> np.ndarray:
    s = _SUPERSAMPLE
    w, h = scene.width * s, scene.height * s
    image = np.broadcast_to(np.asarray(scene.background, dtype=np.float64), (h, w, 3)).copy()
    depth = np.full((h, w), np.inf)
    tri_id = np.full((h, w), -1, dtype=np.int64)
    bary = np.zeros((h, w, 3))
    sx, sy, sz, invw, cw = _to_screen(scene.pos, scene.mvp, w, h)
    # Triangles reaching behind the eye are dropped (OpenGL would clip them).
    idx = np.nonzero((cw > 0.0).all(axis=1))[0]
    _rasterize_kernel(sx[idx], sy[idx], sz[idx], invw[idx], depth, tri_id, bary)
    covered = tri_id >= 0
    if covered.any():
        t = idx[tri_id[covered]]
        b = bary[covered]
        normal, pos, color = (np.einsum("pk,pkc->pc", b, a[t]) for a in (scene.normal, scene.pos, scene.color))
        # Screen y points down, so a counter-clockwise (front-facing) triangle has negative area here.
        area = (sx[t, 1] - sx[t, 0]) * (sy[t, 2] - sy[t, 0]) - (sx[t, 2] - sx[t, 0]) * (sy[t, 1] - sy[t, 0])
        flip = scene.two_sided[t] & (area > 0.0)
        normal[flip] *= -1.0
        image[covered] = _shade(scene, normal, pos, color)
    if len(scene.wire):
        wx, wy, wz, _, ww = _to_screen(scene.wire, scene.mvp, w, h)
        keep = (ww > 0.0).all(axis=1)
        hit = np.zeros((h, w), dtype=np.bool_)
        _wire_kernel(wx[keep], wy[keep], wz[keep], _WIRE_DEPTH_BIAS, s, depth, hit)
        image[hit] = _WIRE_COLOR
    # Average in the stored (sRGB-encoded) values, as an MSAA resolve does.
    pixels = image.reshape(scene.height, s, scene.width, s, 3).mean(axis=(1, 3))
    return np.clip(np.rint(pixels * 255.0), 0, 255).astype(np.uint8)


# ----------------------------------------------------------------------------- public API


def _background(background: Any) -> np.ndarray:
    bg = np.asarray(background, dtype=np.float64).reshape(-1)
    if bg.shape != (3,) or not np.isfinite(bg).all():
        raise TryonError(f"render background must be an RGB triple, got {background!r}")
    return np.clip(bg / 255.0 if bg.max() > 1.0 else bg, 0.0, 1.0)


def render_meshes(
    meshes: Sequence[RenderMesh],
    width: int = 800,
    height: int = 800,
    camera: Camera | None = None,
    background: Any = (1.0, 1.0, 1.0),
    backend: str | None = None,
) -> np.ndarray:
    """Render ``meshes`` to an ``[height, width, 3]`` uint8 RGB image.

    ``camera`` defaults to ``Camera.fit(meshes, "front", aspect=width/height)``.
    ``backend`` is ``"gl"`` (moderngl/EGL), ``"numpy"`` (numba rasteriser) or ``None``
    = automatic: the environment variable ``TRYON_RENDER_BACKEND`` if set, else OpenGL
    when a context can be created, else numpy.
    """
    if isinstance(meshes, RenderMesh):
        meshes = [meshes]
    meshes = list(meshes)
    if not all(isinstance(m, RenderMesh) for m in meshes):
        raise TryonError("render_meshes takes a list of RenderMesh; wrap arrays as RenderMesh(vertices, faces)")
    if not (1 <= int(width) <= 16384 and 1 <= int(height) <= 16384):
        raise TryonError(f"render size must be between 1 and 16384 pixels, got {width}x{height}")
    width, height = int(width), int(height)
    if camera is None:
        if not any(len(m.vertices) for m in meshes):
            raise MeshError("render_meshes: nothing to render (no vertices); pass at least one mesh")
        camera = Camera.fit(meshes, "front", aspect=width / height)
    scene = _pack_scene(meshes, width, height, camera, _background(background))
    choice = backend or os.environ.get("TRYON_RENDER_BACKEND", "auto")
    if choice not in ("auto", "gl", "numpy"):
        raise TryonError(f"unknown render backend {choice!r}; use 'gl', 'numpy' or leave it unset")
    if choice != "numpy":
        gl = _gl_state()
        if gl is not None:
            return _render_gl(gl, scene)
        if choice == "gl":
            raise TryonError(f"OpenGL rendering unavailable ({_GL_FAILURE}); install libEGL or use backend='numpy'")
    return _render_numpy(scene)


def save_png(path: str | os.PathLike[str], image: np.ndarray) -> Path:
    """Write an ``[H, W, 3|4]`` uint8 image as PNG (atomic)."""
    from PIL import Image

    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        raise InputFileError(f"save_png({path}): image must be uint8 [H, W, 3|4], got {img.dtype} {img.shape}")
    out = Path(path)
    with atomic_write(out, "wb") as fh:
        Image.fromarray(img).save(fh, format="PNG")
    return out
