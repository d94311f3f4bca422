"""The exact polyhedral evaluation agrees with the voxel one within the voxel error."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from polyhull.camera import Camera, Intrinsics, look_at_rotation
from polyhull.cell import Zone, mesh_to_manifold
from polyhull.placement.exact import changed_cone, exact_objectives, exact_regions, weighted_volume
from polyhull.placement.labels import (
    Label,
    VoxelGrid,
    boundary_mask,
    free_depth_image,
    label_from_free_depth,
    mesh_mask,
)
from polyhull.placement.objectives import (
    Importance,
    ImportanceRegion,
    MeshArrays,
    ObjectiveParams,
    PlacementProblem,
    evaluate_cameras,
)
from polyhull.raycast import render_depth

ZONE = Zone((0.0, 0.0, 0.0), (3.0, 3.0, 2.0))
GRID = VoxelGrid(ZONE.min, ZONE.max, (75, 75, 50))  # 4 cm voxels
TABLE = trimesh.creation.box(extents=[0.8, 0.6, 0.7]).apply_translation([2.1, 1.0, 0.35])
PERSON = trimesh.creation.box(extents=[0.4, 0.3, 1.7]).apply_translation([1.0, 1.9, 0.85])


def camera(name: str, position, look_at, kind: str = "depth") -> Camera:
    T = np.eye(4)
    T[:3, :3] = look_at_rotation(np.array(position, float), np.array(look_at, float))
    T[:3, 3] = position
    return Camera(name, kind, Intrinsics(96, 72, 70.0, 70.0, 47.5, 35.5), T, near=0.3, far=6.0, noise=0.003)


CAMERAS = [
    camera("a", (0.1, 0.1, 1.9), (1.6, 1.6, 0.4)),
    camera("b", (2.9, 2.9, 1.9), (1.4, 1.3, 0.5), kind="color"),
]


def erode(image: np.ndarray, fill) -> np.ndarray:
    """3 x 3 minimum filter (outside the image counts as ``fill``)."""
    padded = np.pad(image, 1, constant_values=fill)
    h, w = image.shape
    return np.min([padded[i : i + h, j : j + w] for i in range(3) for j in range(3)], axis=0)


def images():
    frees, masks = [], []
    for cam in CAMERAS:
        B = render_depth(cam, [TABLE], 0.0)
        D = render_depth(cam, [TABLE, PERSON], 0.0)
        f, ch = free_depth_image(cam, B, D)
        frees.append(f)
        masks.append(ch)
    return frees, masks


def voxel_volumes(frees, masks, k):
    static = mesh_mask(GRID, [TABLE])
    target = mesh_mask(GRID, [PERSON]) & ~static
    labels = label_from_free_depth(CAMERAS, GRID, frees, masks, k, static, target)
    vv = GRID.voxel_volume
    volumes = {}
    bounds = {}
    for label, name in ((Label.FREE, "free"), (Label.CHANGED, "changed"), (Label.UNDETECTABLE, "undetectable")):
        inside = labels == label
        edge = boundary_mask(inside, GRID.shape)
        volumes[name] = np.count_nonzero(inside) * vv
        bounds[name] = max(np.count_nonzero(edge & inside), np.count_nonzero(edge & ~inside)) * vv
    return volumes, bounds


@pytest.mark.parametrize("k", [1, 2])
def test_exact_volumes_lie_in_the_voxel_bracket(k):
    frees, masks = images()
    # The engine's F(i) lies between the prisms of the 3 x 3-eroded free depth and those
    # of the free depth itself; likewise the changed cone (see polyhull.placement.exact).
    frees_er = [erode(f.astype(np.float64), np.inf) for f in frees]
    masks_er = [erode(m, True) for m in masks]
    exact = exact_regions(
        CAMERAS,
        ZONE,
        frees,
        masks,
        k=k,
        static_solids=[mesh_to_manifold(TABLE, "table")],
        targets=[mesh_to_manifold(PERSON, "person")],
    ).volumes()
    assert sum(exact[n] for n in ("free", "changed", "undetectable")) == pytest.approx(ZONE.volume, rel=1e-6)
    assert exact["static"] == pytest.approx(TABLE.volume, rel=1e-6)
    # Free shrinks with F(i); changed grows with the cones and shrinks with F(i);
    # undetectable shrinks with both.
    brackets = {
        "free": ((frees_er, masks), (frees, masks)),
        "changed": ((frees, masks_er), (frees_er, masks)),
        "undetectable": ((frees, masks), (frees_er, masks_er)),
    }
    for name, (low_in, high_in) in brackets.items():
        low, low_err = voxel_volumes(*low_in, k)
        high, high_err = voxel_volumes(*high_in, k)
        lo = low[name] - low_err[name]
        hi = high[name] + high_err[name]
        assert lo <= exact[name] <= hi, (name, lo, exact[name], hi)
    # And the plain voxel values are close, within 5 % of Z at these small images: most of
    # the gap is the engine's conservative interpolation over oblique surfaces (about half a
    # pixel of depth), which shrinks with the pixel size.
    plain, _ = voxel_volumes(frees, masks, k)
    for name in ("free", "changed", "undetectable"):
        assert abs(plain[name] - exact[name]) < 0.05 * ZONE.volume, name


def test_exact_objectives_agree_with_the_voxel_objectives():
    region = ImportanceRegion(lo=(0.0, 0.0, 0.0), hi=(3.0, 3.0, 1.0), weight=4.0)
    params = ObjectiveParams(w1=1.0, w2=2.0, k=2, importance=Importance(regions=(region,)))
    problem = PlacementProblem(
        grid=GRID,
        floor_z=0.0,
        static_meshes=(MeshArrays.of(TABLE),),
        target_scenes=((MeshArrays.of(PERSON),),),
        params=params,
    )
    voxel = evaluate_cameras(problem, CAMERAS)
    exact = exact_objectives(problem, CAMERAS)
    # Same tolerance as above, 5 % of Z per volume (the small images make the engine's
    # conservative interpolation the main difference), times the weights for f1 to f4.
    tol = 0.05 * ZONE.volume
    for name in ("free", "changed", "undetectable", "free_k", "changed_k", "undetectable_k"):
        assert getattr(voxel, name) == pytest.approx(getattr(exact, name), abs=tol), name
    weight = {"f1": 1.0, "f2": 4.0, "f3": params.w1 + params.w2, "f4": params.w1 + params.w2}
    for name in ("f1", "f2", "f3", "f4"):
        assert voxel[name] == pytest.approx(exact[name], abs=weight[name] * tol), name
    # The engine erodes F(i) (depth edges, oblique surfaces): its free volume is smaller.
    assert exact.free <= voxel.free


def test_changed_cone_and_weighted_volume():
    cam = CAMERAS[0]
    mask = np.zeros(cam.shape, dtype=bool)
    assert changed_cone(cam, mask).is_empty()
    mask[:] = True
    cone = changed_cone(cam, mask)
    assert cone.volume() == pytest.approx(cam.frustum().volume(), rel=1e-6)
    box = ZONE.manifold()
    imp = Importance(regions=(ImportanceRegion((0.0, 0.0, 0.0), (3.0, 3.0, 1.0), 3.0),), default=1.0)
    assert weighted_volume(box, imp) == pytest.approx(3.0 * 9.0 + 9.0)
    assert weighted_volume(box, None) == pytest.approx(18.0)
