"""Motion data model, numpy only: skeletons, BVH files, quaternions, kinematics."""

from styleerd.motion.bvh import BVHError
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import Skeleton

__all__ = ["BVHError", "Motion", "Skeleton"]
