"""The depth simulator: ray-cast frames of a cell with realistic, seeded sensor effects.

:class:`Simulator` renders what every camera of a :class:`~polyhull.cell.Cell` would
measure: the first hit along each pixel-centre ray of the floor, the static obstacles, the
robot at joint positions ``q`` and any target meshes (people), as z-depth [m]. Colour
cameras are rendered the same way; the engine turns their depth into binary change masks.

Sensor effects (:class:`SensorEffects`) are applied in this order, each switchable, all
drawn from ``numpy.random.default_rng`` streams derived from ``(seed, camera index,
effect)`` so that the same seed gives identical frames and switching one effect off does
not change the random draws of the others:

1. flying pixels at depth edges (time-of-flight mixed pixels);
2. depth noise ``N(0, sigma(z))`` with ``sigma(z) = camera.noise * z**2`` [m];
3. dropouts (pixels reported as 0, unknown);
4. out of range: depth outside ``[near, far]`` (and no return, +inf) reported as 0, as
   real drivers do;
5. quantisation to uint16 millimetres.

Flying pixels and dropouts are a depth sensor's (mixed returns at an edge, no return from
a dark or specular patch): a colour camera, whose frame only says where the image
changed, gets neither. Its noise is its declared ``noise`` (0 in the colour fixture) and
its range is the part of the view it is trusted in, so those two apply as declared.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
import numpy.typing as npt
import trimesh

from .camera import Camera
from .errors import PolyhullError, RobotError
from .frames import DepthFrame
from .raycast import MeshCaster, StaticScene
from .typed import ArrayF32, ArrayF64

if TYPE_CHECKING:
    from .cell import Cell

__all__ = ["SensorEffects", "Simulator", "RobotModel", "apply_sensor_effects"]

# Indices of the per-effect random streams (part of the seed derivation: do not reorder).
_STREAM_FLYING = 0
_STREAM_NOISE = 1
_STREAM_DROPOUT = 2


class RobotModel(Protocol):
    """What the simulator needs of a robot: world-frame geometry at joint positions q."""

    def mesh(self, q: ArrayF64) -> trimesh.Trimesh:
        """The robot's surface at joint positions ``q`` [rad], world frame [m]."""
        ...


@dataclass(frozen=True)
class SensorEffects:
    """Which sensor effects the simulator applies, and how strong they are.

    Attributes:
        noise: Add Gaussian depth noise with standard deviation ``camera.noise * z**2``
            [m] at z-depth z [m] (``camera.noise`` is the std at 1 m).
        dropout: Share in [0, 1] of pixels set to 0 (unknown) at random (depth cameras).
        dropout_cluster: Side [px] of the square patches in which pixels drop out. Real
            depth cameras lose pixels in patches (dark or specular spots, multipath), not
            as isolated pixels; 1 gives independent pixels (salt and pepper).
        out_of_range: Report depth outside the camera range ``[near, far]`` [m], and no
            return (+inf), as 0 like real drivers; when False they are kept (+inf stays
            +inf, which REP 117 reads as "no return").
        flying_pixels: Time-of-flight mixed pixels (depth cameras): where the 3 x 3
            neighbourhood spans a depth jump above ``flying_jump``, a pixel is, with
            probability ``flying_share``, replaced by a uniformly random depth between the
            neighbourhood's minimum and maximum (finite values only).
        uint16: Quantise to whole millimetres and return uint16 images, as a uint16
            driver does (0 = unknown; depths beyond 65.535 m become 0).
        flying_jump: Depth jump [m] within a 3 x 3 neighbourhood that makes an edge.
        flying_share: Probability in [0, 1] that an edge pixel becomes a flying pixel.
    """

    noise: bool = True
    dropout: float = 0.002
    dropout_cluster: int = 4
    out_of_range: bool = True
    flying_pixels: bool = True
    uint16: bool = False
    flying_jump: float = 0.1
    flying_share: float = 0.5

    def __post_init__(self) -> None:
        if not (np.isfinite(self.dropout) and 0.0 <= self.dropout <= 1.0):
            raise PolyhullError(f"SensorEffects.dropout must be a share in [0, 1], got {self.dropout!r}")
        if not (isinstance(self.dropout_cluster, int) and 1 <= self.dropout_cluster <= 64):
            raise PolyhullError(
                f"SensorEffects.dropout_cluster must be an integer in [1, 64] px, got {self.dropout_cluster!r}"
            )
        if not (np.isfinite(self.flying_jump) and self.flying_jump > 0.0):
            raise PolyhullError(
                f"SensorEffects.flying_jump must be > 0 m, got {self.flying_jump!r}"
            )
        if not (np.isfinite(self.flying_share) and 0.0 <= self.flying_share <= 1.0):
            raise PolyhullError(
                f"SensorEffects.flying_share must be in [0, 1], got {self.flying_share!r}"
            )

    @classmethod
    def none(cls) -> SensorEffects:
        """No effect at all: the exact ray-cast z-depth (+inf where nothing is hit)."""
        return cls(noise=False, dropout=0.0, out_of_range=False, flying_pixels=False, uint16=False)


def _stream(seed: int, camera_index: int, effect: int) -> np.random.Generator:
    return np.random.default_rng([seed, camera_index, effect])


def _neighbourhood_min_max(
    depth: npt.NDArray[np.float32],
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Minimum and maximum of the finite values in each 3 x 3 neighbourhood, (H, W) each.

    Non-finite values (no return) are ignored; a neighbourhood with no finite value gets
    NaN.
    """
    finite = np.where(np.isfinite(depth), depth, np.float32(np.nan)).astype(np.float32)
    padded = np.pad(finite, 1, mode="constant", constant_values=np.nan)
    # separable: 3-wide along rows, then 3-tall along columns
    row_lo = np.fmin(np.fmin(padded[:, :-2], padded[:, 1:-1]), padded[:, 2:])  # (H+2, W)
    row_hi = np.fmax(np.fmax(padded[:, :-2], padded[:, 1:-1]), padded[:, 2:])
    lo = np.fmin(np.fmin(row_lo[:-2], row_lo[1:-1]), row_lo[2:])
    hi = np.fmax(np.fmax(row_hi[:-2], row_hi[1:-1]), row_hi[2:])
    return lo, hi


def apply_sensor_effects(
    depth: npt.NDArray[np.floating],
    camera: Camera,
    effects: SensorEffects,
    seed: int = 0,
    camera_index: int = 0,
) -> npt.NDArray[np.float32] | npt.NDArray[np.uint16]:
    """Apply ``effects`` to an exact z-depth image of ``camera``.

    Args:
        depth: (H, W) exact z-depth [m], +inf where nothing is hit.
        camera: The camera (noise model, range, and kind: a colour camera gets no
            flying pixels and no dropouts).
        effects: Which effects to apply.
        seed: Non-negative seed; with ``camera_index`` it selects the random streams.
        camera_index: Index of the camera in its cell (independent streams per camera).

    Returns:
        (H, W) float32 depth [m], or uint16 millimetres when ``effects.uint16``.
    """
    if not (isinstance(seed, int | np.integer) and seed >= 0):
        raise PolyhullError(f"seed must be a non-negative integer, got {seed!r}")
    out = np.array(depth, dtype=np.float32)
    if out.ndim != 2:
        raise PolyhullError(f"depth of camera '{camera.name}' must be (H, W), got {out.shape}")
    depth_sensor = camera.kind != "color"
    if effects.flying_pixels and depth_sensor:
        rng = _stream(int(seed), camera_index, _STREAM_FLYING)
        lo, hi = _neighbourhood_min_max(out)
        with np.errstate(invalid="ignore"):
            edge = np.flatnonzero(((hi - lo) > effects.flying_jump) & np.isfinite(out))
        fly = edge[rng.random(len(edge)) < effects.flying_share]
        mix = rng.random(len(fly), dtype=np.float32)
        flat = out.reshape(-1)
        lo_f, hi_f = lo.reshape(-1)[fly], hi.reshape(-1)[fly]
        flat[fly] = lo_f + mix * (hi_f - lo_f)
    if effects.noise and camera.noise > 0.0:
        rng = _stream(int(seed), camera_index, _STREAM_NOISE)
        standard = rng.standard_normal(out.shape, dtype=np.float32)
        finite = np.isfinite(out)  # +inf (no return) stays +inf
        out[finite] += standard[finite] * np.float32(camera.noise) * out[finite] ** 2
    if effects.dropout > 0.0 and depth_sensor:
        rng = _stream(int(seed), camera_index, _STREAM_DROPOUT)
        k = effects.dropout_cluster
        if k == 1:
            out[rng.random(out.shape, dtype=np.float32) < effects.dropout] = 0.0
        else:
            # Patch corners with probability share / k^2, each grown to a k x k patch.
            seeds = rng.random(out.shape, dtype=np.float32) < effects.dropout / (k * k)
            patch = np.zeros((out.shape[0] + k - 1, out.shape[1] + k - 1), dtype=bool)
            for dv in range(k):
                for du in range(k):
                    patch[dv : dv + out.shape[0], du : du + out.shape[1]] |= seeds
            out[patch[: out.shape[0], : out.shape[1]]] = 0.0
    if effects.out_of_range:
        with np.errstate(invalid="ignore"):
            bad = ~((out >= camera.near) & (out <= camera.far))
        out[bad] = 0.0
    if effects.uint16:
        with np.errstate(invalid="ignore"):
            millimetres = np.round(out.astype(np.float64) * 1000.0)
            ok = np.isfinite(millimetres) & (millimetres > 0) & (millimetres <= 65535)
        return np.where(ok, millimetres, 0.0).astype(np.uint16)
    return out


def _load_robot(cell: Cell) -> RobotModel | None:
    if cell.robot is None:
        return None
    from .robot import Robot

    return Robot.from_spec(cell.robot)  # type: ignore[no-any-return]


class Simulator:
    """Ray-cast depth frames of a cell: ``ph.Simulator(cell).render(...)``.

    The Embree scene of the static obstacles and the reference depth of every camera are
    built once; each :meth:`render` only traces the robot and the targets, inside the image
    rectangle each of them covers.

    Args:
        cell: The work cell.
        effects: Default sensor effects of :meth:`render`.
        robot: The robot model; None loads it from ``cell.robot`` (no robot if the cell has
            none).
    """

    def __init__(
        self,
        cell: Cell,
        *,
        effects: SensorEffects = SensorEffects(),  # noqa: B008 - frozen, immutable default
        robot: RobotModel | None = None,
    ) -> None:
        self.cell = cell
        self.effects = effects
        self.robot = robot if robot is not None else _load_robot(cell)
        self._scene = StaticScene([o.mesh for o in cell.obstacles], cell.zone.floor_z)
        self._reference: dict[str, ArrayF32] | None = None

    def reference(self) -> dict[str, ArrayF32]:
        """Reference depth ``B_i`` of every camera: floor and static obstacles only.

        Returns:
            Camera name -> read-only (H, W) float32 z-depth [m], +inf where no hit (cached).
        """
        if self._reference is None:
            reference = {}
            for camera in self.cell.cameras:
                depth = self._scene.render(camera)
                depth.setflags(write=False)
                reference[camera.name] = depth
            self._reference = reference
        return dict(self._reference)

    def _robot_q(self, q: ArrayF64 | Sequence[float] | None) -> ArrayF64:
        if self.robot is None:
            if q is not None and np.size(q) > 0:
                raise RobotError(
                    f"cell '{self.cell.name}' has no robot, but joint positions q = "
                    f"{np.asarray(q).tolist()} were given"
                )
            return np.zeros(0)
        if q is None:
            if self.cell.robot is None:
                raise RobotError("no joint positions q given and the cell has no default robot.q")
            q = self.cell.robot.q
        q_arr = np.asarray(q, dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(q_arr)):
            raise RobotError(f"joint positions q must be finite [rad], got {q_arr.tolist()}")
        return q_arr

    def render_exact(
        self,
        q: ArrayF64 | Sequence[float] | None = None,
        targets: Sequence[trimesh.Trimesh] = (),
    ) -> dict[str, ArrayF32]:
        """Exact z-depth of every camera, without sensor effects.

        Args:
            q: Joint positions [rad] (URDF order); None for the cell's default ``robot.q``.
            targets: Target meshes (people, objects) in the world frame [m].

        Returns:
            Camera name -> (H, W) float32 z-depth [m], +inf where nothing is hit.
        """
        q_arr = self._robot_q(q)
        casters: list[MeshCaster] = []
        if self.robot is not None:
            robot_mesh = self.robot.mesh(q_arr)
            robot_meshes = [robot_mesh] if isinstance(robot_mesh, trimesh.Trimesh) else list(robot_mesh)
            casters.append(MeshCaster(robot_meshes))
        for target in targets:
            casters.append(MeshCaster([target]))
        reference = self.reference()
        depths: dict[str, ArrayF32] = {}
        for camera in self.cell.cameras:
            depth = reference[camera.name].copy()
            rays = self._scene.rays(camera)
            for caster in casters:
                if not caster.is_empty:
                    np.minimum(depth, caster.depth(camera, 1, rays), out=depth)
            depths[camera.name] = depth
        return depths

    def render(
        self,
        q: ArrayF64 | Sequence[float] | None = None,
        targets: Sequence[trimesh.Trimesh] = (),
        seed: int = 0,
        stamp: float = 0.0,
        effects: SensorEffects | None = None,
        *,
        seq: int | None = None,
    ) -> dict[str, DepthFrame]:
        """Depth frames of every camera with the robot at ``q`` and the ``targets``.

        Args:
            q: Joint positions [rad] (URDF order); None for the cell's default ``robot.q``.
            targets: Target meshes (people, objects) in the world frame [m].
            seed: Non-negative seed of all random sensor effects.
            stamp: Acquisition time [s] written into every frame.
            effects: Sensor effects; None for the simulator's default.
            seq: Frame counter written into every frame.

        Returns:
            Camera name -> :class:`~polyhull.frames.DepthFrame`.
        """
        effects = self.effects if effects is None else effects
        exact = self.render_exact(q, targets)
        frames: dict[str, DepthFrame] = {}
        for index, camera in enumerate(self.cell.cameras):
            depth = apply_sensor_effects(exact[camera.name], camera, effects, seed, index)
            # DepthFrame reads uint16 millimetres into float32 metres, as from a driver.
            frames[camera.name] = DepthFrame(
                camera=camera.name, depth=depth, stamp=stamp, seq=seq  # type: ignore[arg-type]
            )
        return frames
