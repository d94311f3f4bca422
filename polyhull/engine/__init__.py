"""The surveillance engine: what changed in the images becomes convex pieces of the region.

The stages, in the order :class:`polyhull.monitor.Monitor` (the pipeline) runs them:

1. :mod:`.static_model` (once, when the monitor is built): per camera the band of depths
   consistent with the empty cell and the static free depth ``f_static``; the fused static
   hull ``C_static`` as a manifold; its plausibility verdicts (the noise sheets over the
   floor and table tops, and whole components); a python-fcl BVH of what remains.
2. :mod:`.robot_pose` and :mod:`.robot_raster`: the padded robot's convex pieces at q
   (link poses, vertices, spheres, shell planes), rasterised into every camera: which
   pixels it covers and the depth where its shadow starts.
3. :mod:`.pixels`: every pixel classified in image space (static, explained by the robot,
   unexplained) and the engine's free depth image of each camera.
4. :mod:`.pieces`: the occluded frustum segments of the unexplained pixels, carved by the
   other cameras' free depth into a union of convex hexahedra, the dynamic part ``Delta``.
5. :mod:`.memory`: the robot shadow's memory, ``C n M`` within a person's reach of what
   the previous cycle saw as a target, as more pieces.
6. :mod:`.dynamic_rules`: the plausibility rules on the dynamic components.
7. :mod:`.refine` and :mod:`polyhull.distance`: the pieces at the distance frontier carved
   finely, the sheets under what stands on a surface, the distance to the robot.

The region of a cycle is ``R = R_static U Delta_kept U sheets`` where ``R_static`` is the
static region after its plausibility rules, ``Delta_kept`` the dynamic pieces (with the
memory's) that pass theirs and ``sheets`` the static noise sheet under every kept dynamic
component.

Around the stages: :mod:`.buffers` (the per-cycle images, reused once no verdict holds
them), :mod:`.threads` (the two threads' shared tasks), :mod:`.boxes` (box queries),
:mod:`.edge_wedges` (static edges and sheet tiles the robot's shadow may meet),
:mod:`.rounding` (directed float32 rounding), :mod:`.warmup` (the monitor's first cycles).
"""
