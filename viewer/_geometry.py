"""Conversions from polyhull's geometry (manifold3d, trimesh, depth frames) to meshcat objects.

manifold3d meshes come as float32 ``vert_properties`` (V, P >= 3; the first three columns are
x, y, z) and uint32 ``tri_verts`` (F, 3); trimesh meshes as float64 vertices and int64 faces.
meshcat wants float32 vertices (V, 3) and uint32 faces (F, 3) and packs them column-major.
Everything here is in the world frame [m].
"""

from __future__ import annotations

from typing import Any

import manifold3d as m3
import meshcat.geometry as mg
import numpy as np
import numpy.typing as npt
import trimesh

from polyhull.camera import Camera
from polyhull.errors import FrameError
from polyhull.frames import DepthFrame
from polyhull.typed import ArrayF32, ArrayF64

from ._colors import depth_colors

__all__ = [
    "ArrayU32",
    "manifold_arrays",
    "trimesh_arrays",
    "mesh_object",
    "colored_mesh_object",
    "tube_object",
    "feature_edges",
    "wireframe_object",
    "segments_object",
    "point_cloud_object",
    "TextLabel",
    "frame_points",
    "cluster_decimate",
    "safe_name",
]

ArrayU32 = npt.NDArray[np.uint32]


def safe_name(name: str) -> str:
    """A meshcat path element for ``name``: ``/`` would split the path, so it becomes ``_``."""
    cleaned = name.replace("/", "_").strip()
    return cleaned or "_"


# -- meshes ---------------------------------------------------------------------------------
def manifold_arrays(manifold: m3.Manifold) -> tuple[ArrayF32, ArrayU32]:
    """Vertices (V, 3) float32 [m] and faces (F, 3) uint32 of a manifold (both may be empty)."""
    mesh = manifold.to_mesh()
    vert_properties = np.asarray(mesh.vert_properties, dtype=np.float32)
    tri_verts = np.asarray(mesh.tri_verts, dtype=np.uint32)
    vertices = np.ascontiguousarray(vert_properties.reshape(-1, max(vert_properties.shape[-1], 3))[:, :3])
    faces = np.ascontiguousarray(tri_verts.reshape(-1, 3))
    return vertices, faces


def trimesh_arrays(mesh: trimesh.Trimesh) -> tuple[ArrayF32, ArrayU32]:
    """Vertices (V, 3) float32 [m] and faces (F, 3) uint32 of a trimesh."""
    vertices = np.ascontiguousarray(np.asarray(mesh.vertices, dtype=np.float32).reshape(-1, 3))
    faces = np.ascontiguousarray(np.asarray(mesh.faces, dtype=np.uint32).reshape(-1, 3))
    return vertices, faces


def mesh_object(
    vertices: ArrayF32 | ArrayF64,
    faces: ArrayU32 | npt.NDArray[np.integer[Any]],
    color: int,
    opacity: float = 1.0,
) -> mg.Mesh:
    """A meshcat mesh (flat shaded, both sides) of vertices (V, 3) [m] and faces (F, 3).

    Transparent meshes do not write depth, so nested regions (M and R inside C) stay
    visible through each other.
    """
    transparent = opacity < 1.0
    material = mg.MeshLambertMaterial(
        color=int(color),
        opacity=float(opacity),
        transparent=transparent,
        depthWrite=not transparent,
        flatShading=True,
    )
    geometry = mg.TriangularMeshGeometry(
        np.asarray(vertices, dtype=np.float32).reshape(-1, 3),
        np.asarray(faces, dtype=np.uint32).reshape(-1, 3),
    )
    return mg.Mesh(geometry, material)


def colored_mesh_object(mesh: trimesh.Trimesh, fallback: int, opacity: float = 1.0) -> mg.Mesh:
    """A meshcat mesh of a trimesh in its own face colours (a URDF material), else ``fallback``.

    One colour over the whole mesh gives a plain material of that colour; several give
    per-vertex colours on unshared vertices (three per face), so faces keep a flat colour.
    """
    vertices, faces = trimesh_arrays(mesh)
    visual = mesh.visual
    if not isinstance(visual, trimesh.visual.ColorVisuals) or visual.kind != "face" or len(faces) == 0:
        return mesh_object(vertices, faces, fallback, opacity)
    rgb = np.asarray(visual.face_colors, dtype=np.float64)[:, :3] / 255.0  # (F, 3)
    if np.all(rgb == rgb[0]):
        r, g, b = (int(round(float(c) * 255.0)) for c in rgb[0])
        return mesh_object(vertices, faces, (r << 16) | (g << 8) | b, opacity)
    flat_vertices = vertices[faces.reshape(-1)]  # (3F, 3)
    flat_faces = np.arange(len(flat_vertices), dtype=np.uint32).reshape(-1, 3)
    colors = np.repeat(rgb, 3, axis=0).astype(np.float32)  # (3F, 3)
    transparent = opacity < 1.0
    material = mg.MeshLambertMaterial(
        color=0xFFFFFF,
        vertexColors=True,
        opacity=float(opacity),
        transparent=transparent,
        depthWrite=not transparent,
        flatShading=True,
    )
    return mg.Mesh(mg.TriangularMeshGeometry(flat_vertices, flat_faces, color=colors), material)


def tube_object(
    start: ArrayF64 | ArrayF32, end: ArrayF64 | ArrayF32, radius: float, color: int
) -> mg.Mesh | None:
    """A cylinder of ``radius`` [m] from ``start`` (3,) to ``end`` (3,) [m] (world frame).

    WebGL draws lines one pixel wide whatever their ``linewidth``, so a segment that must
    read at a glance is a tube. Returns None when the points coincide.
    """
    a = np.asarray(start, dtype=np.float64).reshape(3)
    b = np.asarray(end, dtype=np.float64).reshape(3)
    if not float(np.linalg.norm(b - a)) > 1e-9:
        return None
    tube = trimesh.creation.cylinder(radius=float(radius), segment=np.stack([a, b]), sections=16)
    return mesh_object(*trimesh_arrays(tube), color)


def feature_edges(
    vertices: ArrayF32 | ArrayF64,
    faces: ArrayU32 | npt.NDArray[np.integer[Any]],
    angle: float = np.deg2rad(1.0),
    merge_tol: float = 1e-6,
) -> npt.NDArray[np.int64]:
    """Edges (E, 2) of a triangle mesh where it creases by more than ``angle`` [rad].

    These are the lines of a wireframe without the diagonals of flat faces: the 12 edges of
    a box or a frustum. Vertices closer than ``merge_tol`` [m] are merged first; edges with
    one face (a boundary) or more than two are always kept.
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    # Merge coincident vertices so shared edges are recognised.
    keys = np.round(v / merge_tol).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    f = first[inverse[f]]
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    lengths = np.linalg.norm(normals, axis=1)
    keep_face = lengths > 0.0
    f = f[keep_face]
    normals = normals[keep_face] / lengths[keep_face, None]
    edges = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    face_of_edge = np.repeat(np.arange(len(f)), 3)
    unique, edge_id, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    edge_id = edge_id.reshape(-1)
    order = np.argsort(edge_id, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    keep = counts != 2
    two = np.flatnonzero(counts == 2)
    fa = face_of_edge[order[starts[two]]]
    fb = face_of_edge[order[starts[two] + 1]]
    cos = np.einsum("ij,ij->i", normals[fa], normals[fb])
    keep[two] = cos < np.cos(angle)
    return unique[keep]


def segments_object(points: ArrayF64 | ArrayF32, color: int) -> mg.LineSegments:
    """Line segments from endpoint pairs ``points`` (2K, 3) [m] (segment k is 2k, 2k + 1)."""
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    return mg.LineSegments(
        mg.PointsGeometry(np.ascontiguousarray(p.T)),
        mg.LineBasicMaterial(color=int(color)),
    )


def wireframe_object(
    vertices: ArrayF32 | ArrayF64,
    faces: ArrayU32 | npt.NDArray[np.integer[Any]],
    color: int,
) -> mg.LineSegments:
    """The crease lines of a mesh (see :func:`feature_edges`) as meshcat line segments."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    edges = feature_edges(v, faces)
    return segments_object(v[edges.reshape(-1)], color)


def point_cloud_object(points: ArrayF32 | ArrayF64, colors: ArrayF32, size: float) -> mg.Points:
    """Points (N, 3) [m] with per-point colours (N, 3) in [0, 1], each ``size`` [m] wide."""
    p = np.ascontiguousarray(np.asarray(points, dtype=np.float32).reshape(-1, 3).T)
    c = np.ascontiguousarray(np.asarray(colors, dtype=np.float32).reshape(-1, 3).T)
    return mg.Points(mg.PointsGeometry(p, color=c), mg.PointsMaterial(size=float(size)))


# -- text -----------------------------------------------------------------------------------
class _TextTexture(mg.Texture):  # type: ignore[misc]
    """meshcat's ``_text`` texture: the viewer draws ``text`` on a 256 x 256 canvas."""

    def __init__(self, text: str, font_size: int = 56, font_face: str = "sans-serif") -> None:
        super().__init__()
        self.text = text
        self.font_size = font_size
        self.font_face = font_face

    def lower(self, object_data: dict[str, Any]) -> dict[str, Any]:
        return {
            "uuid": self.uuid,
            "type": "_text",
            "text": self.text,
            "font_size": self.font_size,
            "font_face": self.font_face,
        }


class _SpriteMaterial(mg.Material):  # type: ignore[misc]
    def __init__(self, texture: _TextTexture, size_attenuation: bool = True) -> None:
        super().__init__()
        self.texture = texture
        self.size_attenuation = size_attenuation

    def lower(self, object_data: dict[str, Any]) -> dict[str, Any]:
        return {
            "uuid": self.uuid,
            "type": "SpriteMaterial",
            "map": self.texture.lower_in_object(object_data),
            "transparent": True,
            "depthTest": False,
            "sizeAttenuation": self.size_attenuation,
        }


# meshcat's default perspective camera: 75 degrees of vertical field of view.
VIEW_FOV_DEG = 75.0


class TextLabel(mg.Object):  # type: ignore[misc]
    """A text label that always faces the viewer (a three.js sprite with a text texture).

    The label is a square centred at the path's origin; the text runs across its middle
    (meshcat shrinks the font until the text fits the square's width). Place it with
    ``set_transform``.

    Args:
        text: The text.
        height: Side of the square [m] in the world, when ``screen_size`` is None.
        screen_size: Side of the square as a share of the view's height, the same at
            every distance (three.js ``sizeAttenuation = false``); overrides ``height``.
    """

    def __init__(self, text: str, height: float = 0.6, *, screen_size: float | None = None) -> None:
        mg.SceneElement.__init__(self)
        self.text = text
        self.screen_size = None if screen_size is None else float(screen_size)
        if self.screen_size is None:
            self.height = float(height)
        else:
            # Without attenuation a sprite of scale s spans s / (2 tan(fov / 2)) of the view.
            self.height = self.screen_size * 2.0 * float(np.tan(np.deg2rad(VIEW_FOV_DEG) / 2.0))
        self.material = _SpriteMaterial(_TextTexture(text), size_attenuation=self.screen_size is None)

    def lower(self) -> dict[str, Any]:
        scale = np.diag([self.height, self.height, self.height, 1.0])
        data: dict[str, Any] = {
            "metadata": {"version": 4.5, "type": "Object"},
            "geometries": [],
            "materials": [],
            "textures": [],
            "images": [],
            "object": {
                "uuid": self.uuid,
                "type": "Sprite",
                "material": self.material.uuid,
                "matrix": [float(x) for x in scale.flatten()],
            },
        }
        self.material.lower_in_object(data)
        return data


# -- frames ---------------------------------------------------------------------------------
def frame_points(
    camera: Camera,
    frame: DepthFrame,
    max_points: int,
    bounds: tuple[ArrayF64, ArrayF64] | None = None,
) -> tuple[ArrayF64, ArrayF64]:
    """World points of the valid pixels of a depth frame, evenly subsampled.

    A pixel is valid when its depth is finite and within the camera's range [near, far]
    (0, NaN and +-inf carry no surface). With ``bounds`` (lo (3,), hi (3,)) [m], only
    points inside that box are kept. At most ``max_points`` points are kept, spread evenly
    over the valid ones in row-major order.

    Returns:
        Points (N, 3) in the world frame [m] and their z-depths (N,) [m].

    Raises:
        FrameError: The frame's shape differs from the camera's image shape.
    """
    depth = np.asarray(frame.depth, dtype=np.float64)
    if depth.shape != camera.shape:
        raise FrameError(
            f"frame of camera '{camera.name}': depth shape {depth.shape} does not match the "
            f"camera's image shape (height, width) = {camera.shape}"
        )
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(depth) & (depth >= camera.near) & (depth <= camera.far)
    rows, cols = np.nonzero(valid)
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    z = depth[rows, cols]
    points = camera.unproject(np.column_stack([cols, rows]).astype(np.float64), z)
    if bounds is not None:
        lo, hi = (np.asarray(b, dtype=np.float64).reshape(3) for b in bounds)
        inside = np.all((points >= lo) & (points <= hi), axis=1)
        points, z = points[inside], z[inside]
    if len(points) > max_points:
        pick = np.linspace(0, len(points) - 1, max_points).round().astype(np.int64)
        points, z = points[pick], z[pick]
    return points, z


def frame_cloud(
    camera: Camera,
    frame: DepthFrame,
    max_points: int,
    size: float,
    bounds: tuple[ArrayF64, ArrayF64] | None = None,
) -> mg.Points | None:
    """A point cloud of a depth frame coloured by depth (near purple, far yellow), or None."""
    points, z = frame_points(camera, frame, max_points, bounds)
    if len(points) == 0:
        return None
    return point_cloud_object(points, depth_colors(z, float(z.min()), float(z.max())), size)


# -- display decimation ---------------------------------------------------------------------
def cluster_decimate(
    vertices: ArrayF32 | ArrayF64,
    faces: ArrayU32 | npt.NDArray[np.integer[Any]],
    max_faces: int,
) -> tuple[ArrayF32, ArrayU32]:
    """Fewer triangles for display only, by vertex clustering on a grid.

    Vertices are snapped to the centres of grid cells of a size that brings the face count
    to about ``max_faces``; faces that collapse are dropped. The result looks like the
    mesh but is not a faithful geometric model: use it only to keep HTML files small.

    Returns:
        Vertices (V', 3) float32 and faces (F', 3) uint32; the input unchanged when it
        already has at most ``max_faces`` faces.
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) <= max_faces or len(v) == 0:
        return v.astype(np.float32), f.astype(np.uint32)
    lo = v.min(axis=0)
    area = float(trimesh.Trimesh(v, f, process=False).area)
    # A closed surface of area A meshed with cells of side h has about 2 A / h^2 triangles.
    cell = max(float(np.sqrt(2.0 * area / max_faces)), 1e-6)
    new_v, new_f = v, f
    for _ in range(12):
        keys = np.floor((v - lo) / cell).astype(np.int64)
        _, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        counts = np.bincount(inverse)
        sums = np.zeros((len(counts), 3))
        np.add.at(sums, inverse, v)
        new_v = sums / counts[:, None]
        new_f = inverse[f]
        collapsed = (
            (new_f[:, 0] == new_f[:, 1]) | (new_f[:, 1] == new_f[:, 2]) | (new_f[:, 0] == new_f[:, 2])
        )
        new_f = new_f[~collapsed]
        _, first = np.unique(np.sort(new_f, axis=1), axis=0, return_index=True)
        new_f = new_f[np.sort(first)]
        if len(new_f) <= max_faces:
            break
        cell *= 1.5
    used, compact = np.unique(new_f, return_inverse=True)
    return new_v[used].astype(np.float32), compact.reshape(-1, 3).astype(np.uint32)
