"""Perception: AprilTag detection, PnP poses, camera models, object tracking."""

from rlgp_exec.perception.camera import CAMERAS, CameraIntrinsics, PerceptionError, camera_for_robot
from rlgp_exec.perception.detector import DETECTORS, DetectionResult, ImageStatus, TagDetection, TagDetector
from rlgp_exec.perception.pipeline import Perception, PerceptionReport, SceneUpdate, scene_from_estimates
from rlgp_exec.perception.pose import TagPose, estimate_tag_pose
from rlgp_exec.perception.registry import TagMount, TagRegistry
from rlgp_exec.perception.tracker import ObjectEstimate, ObjectTracker, Observation

__all__ = [
    "CAMERAS",
    "DETECTORS",
    "CameraIntrinsics",
    "DetectionResult",
    "ImageStatus",
    "ObjectEstimate",
    "ObjectTracker",
    "Observation",
    "Perception",
    "PerceptionError",
    "PerceptionReport",
    "SceneUpdate",
    "TagDetection",
    "TagDetector",
    "TagMount",
    "TagPose",
    "TagRegistry",
    "camera_for_robot",
    "estimate_tag_pose",
    "scene_from_estimates",
]
