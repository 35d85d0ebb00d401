"""Files: atomic outputs, OBJ/PLY/GLB meshes, frame sequences."""

from tryon.io.atomic import atomic_output_dir, atomic_path, atomic_write
from tryon.io.frames import load_frames_npz, save_frames_npz, write_obj_sequence
from tryon.io.json_safe import dumps_json, json_safe, write_json
from tryon.io.mesh_io import ObjMesh, read_obj, split_by_uv, write_glb, write_obj, write_ply

__all__ = [
    "atomic_write",
    "atomic_path",
    "atomic_output_dir",
    "ObjMesh",
    "read_obj",
    "split_by_uv",
    "write_obj",
    "write_ply",
    "write_glb",
    "save_frames_npz",
    "load_frames_npz",
    "write_obj_sequence",
    "json_safe",
    "dumps_json",
    "write_json",
]
