"""Tag poses from corners: PnP with the square-tag solver (IPPE_SQUARE), ambiguity handling.

A planar square seen from far away or nearly head-on has two poses that explain its corners almost
equally well (the "flip": the two normals mirror each other about the line of sight). IPPE_SQUARE
returns both, best first; the ratio of their reprojection errors says how ambiguous the view is. An
unambiguous view takes the best pose. An ambiguous one (ratio over AMBIGUITY_RATIO, or the two errors
within the corner noise MIN_CORNER_SIGMA_PX of each other) takes the pose whose tag normal is closer to
a prior normal: the previous estimate's, or the one the scene implies (tags on top faces of upright
objects face up). Without a prior it is rejected, never guessed.

Error figures: with corner noise sigma_px [px] at distance z [m] and focal length f [px], the lateral
position error is ~ sigma_px z / f and the depth error ~ sigma_px z / side_px, where side_px is the
tag's shortest side in the image (~ f s cos(theta) / z: small, far or seen at a grazing angle).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from rlgp_exec.perception.camera import CameraIntrinsics, FloatArray
from rlgp_exec.perception.detector import TagDetection

__all__ = ["AMBIGUITY_RATIO", "TagPose", "estimate_tag_pose", "rotation_angle"]

AMBIGUITY_RATIO = 0.6  # best / second reprojection error above this: the two poses are too close to call
MAX_REPROJ_PX = 2.0  # [px] rms: worse than this, the corners do not belong to a flat square of that size
MIN_CORNER_SIGMA_PX = 0.3  # [px] floor on the corner noise assumed for error figures


@dataclass(frozen=True)
class TagPose:
    """T_camera_tag (4, 4), reprojection rms [px], ambiguity ratio, and 1-sigma error figures."""

    tag_id: int
    T_camera_tag: FloatArray
    reproj_px: float
    ambiguity: float
    pos_std_m: float
    rot_std_rad: float


def rotation_angle(R: FloatArray) -> float:
    """The angle [rad] of a rotation matrix."""
    return float(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))))


def _T(rvec: np.ndarray, tvec: np.ndarray) -> FloatArray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = np.asarray(tvec, float).reshape(3)
    return T


def estimate_tag_pose(
    det: TagDetection, size: float, camera: CameraIntrinsics, prior_normal: FloatArray | None = None
) -> tuple[TagPose | None, str]:
    """(pose, "ok") or (None, reason). ``size`` is the black square's edge [m]; ``prior_normal`` (3,)
    the tag's expected +z axis in the camera frame, used to resolve an ambiguous view."""
    h = size / 2.0
    obj = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
    img = det.corners.astype(np.float64).reshape(4, 1, 2)
    # candidates: IPPE_SQUARE's two poses, plus SQPnP's global optimum (IPPE degrades on exactly
    # fronto-parallel squares); each refined by Levenberg-Marquardt, then ranked by reprojection error
    cands: list[tuple[float, FloatArray]] = []
    for flag in (cv2.SOLVEPNP_IPPE_SQUARE, cv2.SOLVEPNP_SQPNP):
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, camera.K, None, flags=flag)
        for r, t in zip(rvecs[:n], tvecs[:n], strict=True):
            # (3, 1) vectors: solvePnPRefineLM silently misreads (3,) ones
            r, t = cv2.solvePnPRefineLM(obj, img, camera.K, None, r.reshape(3, 1).copy(), t.reshape(3, 1).copy())
            proj, _ = cv2.projectPoints(obj, r, t, camera.K, None)
            rms = float(np.sqrt(np.mean(np.sum((proj.reshape(4, 2) - det.corners) ** 2, axis=1))))
            if np.isfinite(rms):
                cands.append((rms, _T(r, t)))
    if not cands:
        return None, f"tag {det.tag_id}: PnP found no pose"
    cands.sort(key=lambda c: c[0])
    best_rms, best = cands[0]
    # the flip: the best candidate whose normal differs from the best's by more than 5 deg
    flips = [c for c in cands[1:] if float(c[1][:3, 2] @ best[:3, 2]) < math.cos(math.radians(5.0))]
    ambiguity = best_rms / flips[0][0] if flips and flips[0][0] > 1e-12 else 0.0
    if flips and flips[0][0] <= 1e-12:
        ambiguity = 1.0
    rms, T = best_rms, best
    # a flip within the corner noise of the best fits the corners as well: ambiguous whatever the ratio
    # (a 26 px tag: 0.16 vs 0.36 px rms, the best pose 30 deg off the upright truth)
    close = bool(flips) and flips[0][0] - best_rms < MIN_CORNER_SIGMA_PX
    if ambiguity > AMBIGUITY_RATIO or close:
        if prior_normal is None:
            return None, (
                f"tag {det.tag_id}: ambiguous pose (reprojection errors {best_rms:.2f} vs "
                f"{flips[0][0]:.2f} px) and no prior to choose by"
            )
        rms, T = max((cands[0], flips[0]), key=lambda c: float(c[1][:3, 2] @ prior_normal))
    if T[2, 3] <= 0.0:
        return None, f"tag {det.tag_id}: pose behind the camera"
    if rms > MAX_REPROJ_PX:
        return None, f"tag {det.tag_id}: reprojection error {rms:.2f} px over {MAX_REPROJ_PX} px"
    z, f = float(T[2, 3]), (camera.fx + camera.fy) / 2.0
    sigma = max(rms, MIN_CORNER_SIGMA_PX)
    pos_std = math.hypot(sigma * z / f, sigma * z / max(det.side_px, 1.0))
    rot_std = sigma / max(det.side_px, 1.0) * 2.0  # [rad] ~ corner error over the tag's extent in pixels
    return TagPose(det.tag_id, T, rms, ambiguity, pos_std, rot_std), "ok"
