"""From a camera image to object poses in the world, and from those to the scene the planner sees.

:class:`Perception` runs detection -> PnP -> world frame -> tracker for one image at a time, with the
camera pose from the robot's FK at the image's time stamp. Nothing in it raises on a bad detection:
unknown tags, tiny tags, ambiguous or inconsistent poses become reasons in the report. A bad image
(wrong type, dtype, shape) or a bad camera pose raises :class:`PerceptionError` before anything
changes. :func:`scene_from_estimates` puts fresh estimates into a scene for planning and says which
object poses are uncertain (never seen, stale, or tipped over).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np

from rlgp_exec.perception.camera import CameraIntrinsics, FloatArray, PerceptionError
from rlgp_exec.perception.detector import DetectionResult, ImageStatus, TagDetector
from rlgp_exec.perception.pose import estimate_tag_pose
from rlgp_exec.perception.registry import TagRegistry
from rlgp_exec.perception.resting import RestingSupports
from rlgp_exec.perception.tracker import ObjectTracker, Observation
from rlgp_exec.scene import Scene

__all__ = ["MAX_TILT_RAD", "Perception", "PerceptionReport", "SceneUpdate", "scene_from_estimates"]

log = logging.getLogger(__name__)
MAX_TILT_RAD = math.radians(10.0)  # an object tilted more than this is not upright: its pose is uncertain


@dataclass(frozen=True)
class PerceptionReport:
    stamp: float
    image_status: ImageStatus
    detect_ms: float
    observations: tuple[Observation, ...]
    rejected: tuple[str, ...]  # reasons, one per rejected tag
    updated: tuple[str, ...]  # objects whose estimates this image updated


def _check_pose(T: object) -> FloatArray:
    M = np.asarray(T, dtype=float)
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise PerceptionError(f"T_world_camera must be a finite (4, 4) matrix, got shape {M.shape}")
    if not np.allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-6) or not np.allclose(M[3], [0, 0, 0, 1]):
        raise PerceptionError("T_world_camera is not a rigid transform")
    return M


def _check_stamp(stamp: float) -> None:
    if not math.isfinite(stamp):
        raise PerceptionError(f"image stamp must be a finite time [s], got {stamp}")


class Perception:
    def __init__(
        self,
        registry: TagRegistry,
        camera: CameraIntrinsics,
        detector: TagDetector | None = None,
        tracker: ObjectTracker | None = None,
        max_pos_std_m: float = math.inf,
        supports: RestingSupports | None = None,
    ) -> None:
        """``max_pos_std_m`` [m]: a tag pose whose error figure is larger (a small tag, far away) places
        no object: its depth error along the ray would put a resting object into or above its support.
        ``supports``: each observation of an object resting on one of them is moved along its viewing ray
        onto it before it is fused (None: observations are fused as PnP gives them)."""
        self.registry, self.camera = registry, camera
        self.max_pos_std_m = max_pos_std_m
        self.supports = supports
        self.too_far = 0  # tag poses not fused: error figure over max_pos_std_m
        self.detector = detector or TagDetector()
        self.tracker = tracker or ObjectTracker()

    def process(self, image: object, T_world_camera: object, stamp: float) -> PerceptionReport:
        """Detect tags in ``image`` taken from ``T_world_camera`` at ``stamp`` [s]; update the tracker."""
        T_wc = _check_pose(T_world_camera)
        _check_stamp(stamp)
        if isinstance(image, np.ndarray) and image.ndim >= 2:
            h, w = image.shape[:2]
            if (w, h) != (self.camera.width, self.camera.height):
                raise PerceptionError(
                    f"image is {w}x{h} but the camera model is {self.camera.width}x{self.camera.height}"
                )
        return self.locate(self.detector.detect(image), T_wc, stamp)

    def locate(
        self, result: DetectionResult, T_world_camera: object, stamp: float, lifted: frozenset[str] = frozenset()
    ) -> PerceptionReport:
        """The second half of :meth:`process`: PnP, world frame and tracker for tags already detected (a
        caller sharing the tracker across threads detects outside its lock and locates inside it).
        ``lifted``: objects known not to rest on anything (in the hand): not moved onto a support."""
        T_wc = _check_pose(T_world_camera)
        _check_stamp(stamp)
        rejected = [why for _, why in result.rejected]
        if result.status is ImageStatus.BLANK:
            log.warning("blank image at t=%.3f: nothing to detect", stamp)
        observations = []
        R_cw = T_wc[:3, :3].T
        others = {} if self.supports is None else {
            n: e.T_world_object for n, e in self.tracker.estimates().items() if n not in lifted
        }
        for det in result.detections:
            mount = self.registry.get(det.tag_id)
            if mount is None:
                rejected.append(f"tag {det.tag_id} is not in the registry (known: {self.registry.ids})")
                continue
            prev = self.tracker.estimate(mount.object)
            if prev is not None and not self.tracker.is_stale(mount.object, stamp):
                normal_w = prev.T_world_object[:3, :3] @ mount.T_object_tag[:3, 2]
            else:  # the scene's prior: objects stand upright, tags on their tops face up
                normal_w = np.array([0.0, 0.0, 1.0])
            pose, why = estimate_tag_pose(det, mount.size, self.camera, R_cw @ normal_w)
            if pose is None:
                rejected.append(why)
                continue
            if pose.pos_std_m > self.max_pos_std_m:  # expected on far views: counted, not warned
                self.too_far += 1
                log.debug("tag %d: error figure %.0f mm over %.0f mm: too far to place %s", det.tag_id,
                          pose.pos_std_m * 1e3, self.max_pos_std_m * 1e3, mount.object)
                continue
            T_wt = T_wc @ pose.T_camera_tag
            T_wo = T_wt @ np.linalg.inv(mount.T_object_tag)
            if self.supports is not None and mount.object not in lifted:
                T_wo = self.supports.onto_support(mount.object, T_wo, T_wt[:3, 3], T_wc[:3, 3], pose.pos_std_m, others)
            observations.append(Observation(mount.object, det.tag_id, T_wo, pose.pos_std_m, pose.rot_std_rad, stamp))
        for why in rejected[len(result.rejected) :]:
            log.warning("tag rejected: %s", why)
        updated = self.tracker.update(observations)
        return PerceptionReport(
            stamp, result.status, result.detect_ms, tuple(observations), tuple(rejected), tuple(updated)
        )


@dataclass(frozen=True)
class SceneUpdate:
    scene: Scene
    updated: frozenset[str]  # poses replaced by fresh estimates
    uncertain: frozenset[str]  # poses the planner should not trust: unseen, stale or tipped over


def scene_from_estimates(scene: Scene, tracker: ObjectTracker, now: float) -> SceneUpdate:
    """The scene with fresh, upright estimates in place of the file's object poses (x, y, z, yaw)."""
    objects, updated, uncertain = [], set(), set()
    for obj in scene.objects:
        est = tracker.estimate(obj.name)
        if est is None or tracker.is_stale(obj.name, now):
            objects.append(obj)
            uncertain.add(obj.name)
            continue
        R = est.T_world_object[:3, :3]
        tilt = math.acos(max(-1.0, min(1.0, float(R[2, 2]))))
        if tilt > MAX_TILT_RAD:
            log.warning(
                "%s is tilted %.0f deg: not upright, pose kept from before and marked uncertain",
                obj.name,
                math.degrees(tilt),
            )
            objects.append(obj)
            uncertain.add(obj.name)
            continue
        x, y, z = (float(v) for v in est.T_world_object[:3, 3])
        yaw = math.atan2(R[1, 0], R[0, 0])
        objects.append(replace(obj, pose=(x, y, z, yaw)))
        updated.add(obj.name)
    return SceneUpdate(replace(scene, objects=tuple(objects)), frozenset(updated), frozenset(uncertain))
