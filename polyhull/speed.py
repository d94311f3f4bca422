"""Speed and separation monitoring: from the minimum distance to a robot speed.

Two profiles:

- ``iso``: ISO/TS 15066 protective separation distance
  ``S_p = v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r`` with ``S_s = v_r T_s / 2``
  (constant deceleration from v_r over T_s) unless a fixed stopping distance is given. The
  reaction time T_r includes the measured cycle latency. ``v_h`` is 2.0 m/s when the
  distance is under 0.5 m and 1.6 m/s otherwise (ISO 13855). The monitor allows the largest
  v_r with ``d >= S_p``.
- ``ramp``: the paper's distance-velocity ramp: stop below d0, full speed above d1, linear
  in between.

Any extra margin (the robot padding of the occlusion) is added to ``S_p`` / d0 and d1.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from .cell import SafetyParams

__all__ = ["SpeedDecision", "decide_speed", "protective_separation_distance"]


class SpeedDecision(NamedTuple):
    """The result of speed and separation monitoring.

    Attributes:
        speed_scale: Allowed share of the robot's maximum speed in [0, 1]; 0 means stop.
        allowed_speed: Allowed robot speed v_r in [m/s].
        separation: The protective separation distance S_p at that speed [m] (iso), or the
            stop distance d0 (ramp).
    """

    speed_scale: float
    allowed_speed: float
    separation: float


def protective_separation_distance(
    robot_speed: float, distance: float, params: SafetyParams, latency: float, margin: float = 0.0
) -> float:
    """S_p [m] for robot speed v_r [m/s] at distance d [m], cycle latency [s] and margin [m]."""
    v_h = params.human_speed_close if distance < params.close_distance else params.human_speed
    t_r = params.reaction_time + latency
    t_s = params.stopping_time
    if params.stopping_distance is None:
        s_s = robot_speed * t_s / 2.0
    else:
        s_s = params.stopping_distance * robot_speed / params.robot_speed_max
    return (
        v_h * (t_r + t_s)
        + robot_speed * t_r
        + s_s
        + params.intrusion_distance
        + params.sensor_uncertainty
        + params.robot_uncertainty
        + margin
    )


def decide_speed(
    distance: float, params: SafetyParams, latency: float = 0.0, margin: float = 0.0
) -> SpeedDecision:
    """Largest safe robot speed for the minimum distance ``distance`` [m].

    Args:
        distance: Minimum distance between the region and the robot [m] (inf if none).
        params: Safety parameters.
        latency: Measured cycle latency [s], added to the reaction time.
        margin: Extra distance [m] always added to the separation (robot padding).

    Returns:
        The speed decision; a non-finite or non-positive distance stops the robot.
    """
    v_max = params.robot_speed_max
    if math.isnan(distance) or distance <= 0.0:
        return SpeedDecision(0.0, 0.0, math.inf)
    if params.profile == "ramp":
        d0 = params.ramp_stop_distance + margin
        d1 = params.ramp_full_distance + margin
        scale = min(max((distance - d0) / (d1 - d0), 0.0), 1.0)
        return SpeedDecision(scale, scale * v_max, d0)
    if math.isinf(distance):
        return SpeedDecision(1.0, v_max, protective_separation_distance(v_max, distance, params, latency, margin))
    s0 = protective_separation_distance(0.0, distance, params, latency, margin)
    slope = protective_separation_distance(1.0, distance, params, latency, margin) - s0
    v = (distance - s0) / slope if slope > 0 else (v_max if distance >= s0 else 0.0)
    v = min(max(v, 0.0), v_max)
    return SpeedDecision(v / v_max, v, protective_separation_distance(v, distance, params, latency, margin))
