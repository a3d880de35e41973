"""nav2_msgs where installed: the particle cloud with weights and the ``set_initial_pose`` service.

``nav2_msgs`` comes with nav2 on a ROS 2 machine, and from ``make``'s ``interfaces/`` on a PyPI
install; without it :data:`ParticleCloud` and :data:`SetInitialPose` are None and the node
offers neither (``~/candidates`` still carries the poses).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.localizer import Estimate
from .conversions import pose_to_pose_msg, seconds_to_stamp

try:
    from nav2_msgs.msg import Particle, ParticleCloud
    from nav2_msgs.srv import SetInitialPose
except ImportError:  # neither nav2 nor make's interfaces/
    Particle = ParticleCloud = SetInitialPose = None

__all__ = ["Particle", "ParticleCloud", "SetInitialPose", "estimate_to_particle_cloud"]


def estimate_to_particle_cloud(estimate: Estimate, frame_id: str = "map", max_particles: int = 5000) -> Any:
    """The estimate's candidates with their weights (uniform where the method gives none) as ``nav2_msgs/ParticleCloud``."""
    if ParticleCloud is None:
        raise RuntimeError("nav2_msgs is not installed (nav2 has it; a PyPI install gets it from `make`)")
    poses = estimate.candidates[:max_particles]
    weights = (np.full(len(poses), 1.0 / max(len(poses), 1)) if estimate.candidate_weights is None
               else np.asarray(estimate.candidate_weights, dtype=np.float64)[:max_particles])
    msg = ParticleCloud()
    msg.header.stamp = seconds_to_stamp(estimate.stamp)
    msg.header.frame_id = frame_id
    msg.particles = [Particle(pose=pose_to_pose_msg(p), weight=float(w)) for p, w in zip(poses, weights, strict=False)]
    return msg
