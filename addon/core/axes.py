"""Forward / Up axis options, as Blender's own importers (OBJ, glTF, PLY) offer them.

A file's frame is named by the file axis that becomes Blender's forward (+Y) and the one that
becomes Blender's up (+Z); `axis_matrix(forward, up)` is the rotation (or, for a
left-handed choice, never: the third axis always follows from the right-hand rule) taking
file coordinates to Blender's. It equals `bpy_extras.io_utils.axis_conversion(from_forward=
forward, from_up=up)` (a test holds it to that) but needs no bpy, so the command line and
scripts convert the same way the operators do. The matrices are signed permutations with
exact 0 and +-1 entries.

The default per file format lives in `formats.registry` (`SplatFormat.axes`): every reader
returns Gaussians in the 3DGS .ply frame (x right, y down, z forward, as COLMAP), so a scene
captured with upright photos stands upright with forward "Z" and up "-Y".
"""

from __future__ import annotations

import numpy as np

# Identifiers in Blender's order and spelling (bpy_extras.io_utils.orientation_helper).
AXES = ("X", "Y", "Z", "-X", "-Y", "-Z")
IDENTITY = ("Y", "Z")  # forward, up: Blender's own frame


def parse_axis(text: str) -> str:
    """'x', '+Y', '-z', 'NEGATIVE_Z', ... -> Blender's identifier ('X', 'Y', '-Z', ...)."""
    name = str(text).strip().upper().replace("NEGATIVE_", "-").lstrip("+")
    if name not in AXES:
        raise ValueError(f"unknown axis {text!r}; expected one of X, Y, Z, -X, -Y, -Z")
    return name


def _vector(axis: str) -> np.ndarray:
    axis = parse_axis(axis)
    v = np.zeros(3)
    v["XYZ".index(axis[-1])] = -1.0 if axis.startswith("-") else 1.0
    return v


def axis_matrix(forward: str, up: str) -> np.ndarray:
    """(3, 3) rotation taking a file whose `forward` / `up` axes are given to Blender's frame
    (forward +Y, up +Z). Raises ValueError when both name the same axis line."""
    f, u = _vector(forward), _vector(up)
    if abs(float(f @ u)) > 0.5:
        raise ValueError(f"forward ({forward}) and up ({up}) must be different axes")
    right = np.cross(f, u)  # file direction that becomes Blender's +X
    return np.stack([right, f, u])  # rows: what lands on Blender's X, Y, Z


def axis_matrix4(forward: str, up: str) -> np.ndarray:
    """`axis_matrix` as an affine 4x4."""
    m = np.eye(4)
    m[:3, :3] = axis_matrix(forward, up)
    return m


def snap(matrix: np.ndarray, tolerance: float = 1e-6) -> np.ndarray:
    """`matrix` with entries within `tolerance` of -1, 0 or 1 made exact. Blender keeps an
    object's rotation as float32 angles, so an object turned by exactly 90 degrees holds
    cos = -4.4e-8 instead of 0; snapping lets export undo an import's axis conversion exactly
    (bit-exact data), and changes any other matrix by less than a float32 rounding."""
    m = np.array(matrix, np.float64)
    for target in (-1.0, 0.0, 1.0):
        m[np.abs(m - target) <= tolerance] = target
    return m
