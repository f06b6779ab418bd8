"""Camera messages as CDR bytes without ROS (rosbags, Humble types): ``sensor_msgs/msg/Image``,
``sensor_msgs/msg/CameraInfo`` and ``sensor_msgs/msg/CompressedImage``, encoded and decoded defensively.

Decoders never raise on bad bytes: they return a :class:`~rlgp_exec.hal.ros_codec.Rejected` naming what
was wrong (too large, no CDR header, truncated, an encoding we do not read, a size that does not match
the data, zero or huge dimensions, a camera matrix that is not a camera), so a receiver counts it, warns
and carries on without a pose.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from rlgp_exec.hal.ros_codec import Rejected, _header, _ser, _t, decode

__all__ = [
    "ENCODINGS",
    "MAX_IMAGE_BYTES",
    "MAX_SIDE_PX",
    "CameraModel",
    "ImageFrame",
    "encode_camera_info",
    "encode_compressed",
    "encode_image",
    "parse_camera_info",
    "parse_compressed",
    "parse_image",
]

MAX_SIDE_PX = 4096  # [px] wider or taller than this is not a head camera's image
MIN_SIDE_PX = 16  # [px] what the camera model accepts (perception.camera.CameraIntrinsics)
MAX_IMAGE_BYTES = MAX_SIDE_PX * MAX_SIDE_PX * 4 + 4096  # [bytes] a payload above this is dropped unread
MAX_INFO_BYTES = 16 * 1024  # [bytes] a CameraInfo is a few hundred bytes
ENCODINGS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}  # encoding -> channels (8 bit each)


@dataclass(frozen=True)
class ImageFrame:
    """An image as the detector takes it: (H, W, 3) RGB or (H, W) grey uint8, stamped [s] in the robot's
    clock, in the optical frame ``frame_id``."""

    stamp: float
    frame_id: str
    image: np.ndarray

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) [px]."""
        return int(self.image.shape[1]), int(self.image.shape[0])


@dataclass(frozen=True)
class CameraModel:
    """A CameraInfo's pinhole model of the (rectified) image: size [px] and the camera matrix K (3, 3)."""

    stamp: float
    frame_id: str
    width: int
    height: int
    K: np.ndarray


def _stamp_s(header: Any) -> float:
    st = header.stamp
    return float(st.sec) + float(st.nanosec) * 1e-9


def _check_size(what: str, width: int, height: int) -> Rejected | None:
    if not (MIN_SIDE_PX <= width <= MAX_SIDE_PX and MIN_SIDE_PX <= height <= MAX_SIDE_PX):
        return Rejected(
            "bad_size", f"{what}: {width}x{height} px outside [{MIN_SIDE_PX}, {MAX_SIDE_PX}] on either side"
        )
    return None


# ---------------------------------------------------------------------- encoders
def encode_image(stamp: float, frame_id: str, rgb: np.ndarray) -> bytes:
    """sensor_msgs/Image, rgb8, from an (H, W, 3) uint8 RGB array."""
    img = np.ascontiguousarray(rgb, dtype=np.uint8)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"encode_image takes an (H, W, 3) RGB array, got shape {img.shape}")
    h, w = img.shape[:2]
    # rosbags lays out the message without its pixels, which end it (a uint32 count, then the bytes):
    # the same bytes as serialising the whole array, which costs ~20x more (~12 ms for 640x480)
    msg = _t("sensor_msgs/msg/Image")(
        header=_header(stamp, frame_id), height=h, width=w, encoding="rgb8", is_bigendian=0, step=3 * w,
        data=np.zeros(0, np.uint8),
    )
    head = _ser(msg, "sensor_msgs/msg/Image")
    return head[:-4] + struct.pack("<I", img.size) + img.tobytes()


def encode_compressed(stamp: float, frame_id: str, rgb: np.ndarray, quality: int = 90) -> bytes:
    """sensor_msgs/CompressedImage, JPEG, from an (H, W, 3) uint8 RGB array."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    msg = _t("sensor_msgs/msg/CompressedImage")(
        header=_header(stamp, frame_id), format="rgb8; jpeg compressed bgr8", data=np.asarray(buf, np.uint8).reshape(-1)
    )
    return _ser(msg, "sensor_msgs/msg/CompressedImage")


def encode_camera_info(stamp: float, frame_id: str, width: int, height: int, K: np.ndarray) -> bytes:
    """sensor_msgs/CameraInfo of a rectified pinhole image: K and P = [K | 0], no distortion, R = I."""
    K = np.asarray(K, float).reshape(3, 3)
    P = np.hstack([K, np.zeros((3, 1))])
    msg = _t("sensor_msgs/msg/CameraInfo")(
        header=_header(stamp, frame_id), height=int(height), width=int(width), distortion_model="plumb_bob",
        d=np.zeros(5), k=K.reshape(-1), r=np.eye(3).reshape(-1), p=P.reshape(-1), binning_x=0, binning_y=0,
        roi=_t("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )
    return _ser(msg, "sensor_msgs/msg/CameraInfo")


# ---------------------------------------------------------------------- decoders
def parse_image(payload: bytes) -> ImageFrame | Rejected:
    """The image of a sensor_msgs/Image payload (rgb8, bgr8, rgba8, bgra8 or mono8) as RGB or grey."""
    m = decode(payload, "sensor_msgs/msg/Image", MAX_IMAGE_BYTES)
    if isinstance(m, Rejected):
        return m
    enc = str(m.encoding)
    w, h, step = int(m.width), int(m.height), int(m.step)
    if enc not in ENCODINGS:
        return Rejected("encoding", f"Image: encoding {enc!r} not read; valid: {sorted(ENCODINGS)}")
    bad = _check_size("Image", w, h)
    if bad is not None:
        return bad
    c = ENCODINGS[enc]
    data = np.asarray(m.data, dtype=np.uint8)
    if step < w * c or step > w * c + 64:
        return Rejected("inconsistent", f"Image: step {step} for {w} px of {enc} ({w * c} bytes a row)")
    if data.size != step * h:
        return Rejected("inconsistent", f"Image: {data.size} data bytes, {h} rows of {step} expected {step * h}")
    rows = data.reshape(h, step)[:, : w * c]
    if c == 1:
        img = rows.reshape(h, w).copy()
    else:
        img = rows.reshape(h, w, c)[:, :, :3]
        img = np.ascontiguousarray(img[:, :, ::-1] if enc.startswith("bgr") else img)
    return ImageFrame(_stamp_s(m.header), str(m.header.frame_id), img)


def parse_compressed(payload: bytes) -> ImageFrame | Rejected:
    """The image of a sensor_msgs/CompressedImage payload (JPEG or PNG) as RGB."""
    m = decode(payload, "sensor_msgs/msg/CompressedImage", MAX_IMAGE_BYTES)
    if isinstance(m, Rejected):
        return m
    fmt = str(m.format).lower()
    if "jpeg" not in fmt and "png" not in fmt:
        return Rejected("encoding", f"CompressedImage: format {fmt!r} is neither jpeg nor png")
    data = np.asarray(m.data, dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if img is None:
        return Rejected("malformed", f"CompressedImage: {data.size} bytes do not decode as {fmt!r}")
    bad = _check_size("CompressedImage", img.shape[1], img.shape[0])
    if bad is not None:
        return bad
    return ImageFrame(_stamp_s(m.header), str(m.header.frame_id), cv2.cvtColor(img, cv2.COLOR_BGR2RGB))


def parse_camera_info(payload: bytes) -> CameraModel | Rejected:
    """The rectified image's pinhole model of a sensor_msgs/CameraInfo payload: P's left (3, 3) block
    (the camera matrix of the rectified image), or K where P is all zero (an uncalibrated driver)."""
    m = decode(payload, "sensor_msgs/msg/CameraInfo", MAX_INFO_BYTES)
    if isinstance(m, Rejected):
        return m
    w, h = int(m.width), int(m.height)
    bad = _check_size("CameraInfo", w, h)
    if bad is not None:
        return bad
    k, p = np.asarray(m.k, float), np.asarray(m.p, float)
    if k.size != 9 or p.size != 12 or not (np.all(np.isfinite(k)) and np.all(np.isfinite(p))):
        return Rejected("invalid", "CameraInfo: K or P not finite")
    K = p.reshape(3, 4)[:, :3] if np.any(p) else k.reshape(3, 3)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (fx > 0 and fy > 0) or abs(K[0, 1]) > 1e-9 * fx or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        return Rejected("singular", f"CameraInfo: not a pinhole camera matrix: {K.round(3).tolist()}")
    if not (math.isfinite(cx) and math.isfinite(cy) and -w <= cx <= 2 * w and -h <= cy <= 2 * h):
        return Rejected("invalid", f"CameraInfo: principal point ({cx}, {cy}) far outside {w}x{h}")
    return CameraModel(_stamp_s(m.header), str(m.header.frame_id), w, h, K.copy())
