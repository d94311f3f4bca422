"""Sensor placement quality and optimisation (paper section 4).

Score where the cameras of a cell hang with the objectives of paper section 4, over people
sampled on the walkable floor, and optimise them on the cell's mounting surfaces::

    import polyhull as ph
    from polyhull import placement as pl

    cell = ph.load_cell("fixtures/cells/paper_cell.toml")
    scenes = pl.sample_target_scenes(cell, n_scenes=6)
    problem = pl.PlacementProblem.from_cell(cell, scenes, grid_shape=(126, 90, 66))
    before = pl.evaluate_cameras(problem, cell.cameras)      # f1 .. f4 [m^3, weighted]
    param = pl.CameraParameterisation.for_cell(cell)
    with pl.make_executor(workers=2) as executor:
        result = pl.optimize(problem, param, "f3", pl.StopCriteria(max_evals=300),
                             executor, x0=param.encode(cell.cameras))
    result.cameras, result.best.f3, result.optimum.f3

It needs the ``placement`` extra (cmaes, matplotlib, dask[distributed]) for the optimiser,
the plot and distributed runs; the objectives themselves only need the core.
"""

from .exact import ExactRegions as ExactRegions
from .exact import changed_cone as changed_cone
from .exact import exact_objectives as exact_objectives
from .exact import exact_regions as exact_regions
from .exact import weighted_volume as weighted_volume
from .labels import PAPER_GRID as PAPER_GRID
from .labels import GridProjection as GridProjection
from .labels import Label as Label
from .labels import VoxelGrid as VoxelGrid
from .labels import boundary_mask as boundary_mask
from .labels import camera_votes as camera_votes
from .labels import free_depth_image as free_depth_image
from .labels import fuse_labels as fuse_labels
from .labels import label_from_free_depth as label_from_free_depth
from .labels import label_voxels as label_voxels
from .labels import mesh_mask as mesh_mask
from .labels import project_grid as project_grid
from .objectives import OBJECTIVES as OBJECTIVES
from .objectives import Importance as Importance
from .objectives import ImportanceRegion as ImportanceRegion
from .objectives import MeshArrays as MeshArrays
from .objectives import ObjectiveName as ObjectiveName
from .objectives import ObjectiveParams as ObjectiveParams
from .objectives import Objectives as Objectives
from .objectives import PlacementProblem as PlacementProblem
from .objectives import PreparedProblem as PreparedProblem
from .objectives import evaluate_cameras as evaluate_cameras
from .objectives import label_scene as label_scene
from .objectives import prepare as prepare
from .optimizer import CameraParameterisation as CameraParameterisation
from .optimizer import CameraSetting as CameraSetting
from .optimizer import InlineExecutor as InlineExecutor
from .optimizer import OptimizationResult as OptimizationResult
from .optimizer import StopCriteria as StopCriteria
from .optimizer import evaluate_vector as evaluate_vector
from .optimizer import make_executor as make_executor
from .optimizer import optimize as optimize
from .optimizer import optimize_counts as optimize_counts
from .optimizer import pan_tilt_rotation as pan_tilt_rotation
from .report import build_report as build_report
from .report import markdown_report as markdown_report
from .report import plot_convergence as plot_convergence
from .report import write_cell_toml as write_cell_toml
from .report import write_json as write_json
from .report import write_markdown as write_markdown
from .targets import PersonPlacement as PersonPlacement
from .targets import TargetScene as TargetScene
from .targets import sample_target_scenes as sample_target_scenes

__all__ = [
    "OBJECTIVES",
    "PAPER_GRID",
    "CameraParameterisation",
    "CameraSetting",
    "ExactRegions",
    "GridProjection",
    "Importance",
    "ImportanceRegion",
    "InlineExecutor",
    "Label",
    "MeshArrays",
    "ObjectiveName",
    "ObjectiveParams",
    "Objectives",
    "OptimizationResult",
    "PersonPlacement",
    "PlacementProblem",
    "PreparedProblem",
    "StopCriteria",
    "TargetScene",
    "VoxelGrid",
    "boundary_mask",
    "build_report",
    "camera_votes",
    "changed_cone",
    "evaluate_cameras",
    "evaluate_vector",
    "exact_objectives",
    "exact_regions",
    "free_depth_image",
    "fuse_labels",
    "label_from_free_depth",
    "label_scene",
    "label_voxels",
    "make_executor",
    "markdown_report",
    "mesh_mask",
    "optimize",
    "optimize_counts",
    "pan_tilt_rotation",
    "plot_convergence",
    "prepare",
    "project_grid",
    "sample_target_scenes",
    "weighted_volume",
    "write_cell_toml",
    "write_json",
    "write_markdown",
]
