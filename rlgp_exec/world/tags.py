"""AprilTag (tag36h11) quads for PyBullet: an OBJ quad with UVs plus a PNG texture per tag id.

PyBullet maps textures onto box primitives badly, but renders a textured OBJ quad well enough for
detection at ~1 mm. Files are generated on first use into a cache folder (never committed):
``$RLGP_EXEC_CACHE`` or ``~/.cache/rlgp-exec``, ``tags/``.

Convention: the quad lies in its frame's xy-plane facing +z; the tag image's right edge points
along +x and its top edge along +y. ``size`` is the black square's edge; a one-cell white quiet
zone surrounds it, so the quad's edge is ``size * 10 / 8``.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from rlgp_exec.errors import RlgpError

__all__ = ["QUIET_ZONE_RATIO", "tag_files", "tag_image", "tag_quad_size"]

QUIET_ZONE_RATIO = 10.0 / 8.0  # quad edge / black-square edge
_CELLS = 8  # tag36h11 black square: 6 data cells + a 1-cell black border on each side
_PX_PER_CELL = 32
_OBJ = """# unit quad, facing +z, UVs over the whole texture
v -0.5 -0.5 0
v 0.5 -0.5 0
v 0.5 0.5 0
v -0.5 0.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
f 1/1/1 2/2/1 3/3/1
f 1/1/1 3/3/1 4/4/1
"""


def cache_dir() -> Path:
    root = Path(os.environ.get("RLGP_EXEC_CACHE", Path.home() / ".cache" / "rlgp-exec"))
    folder = root / "tags"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def tag_quad_size(size: float) -> float:
    """Edge of the quad [m] for a tag whose black square is ``size`` [m]."""
    return size * QUIET_ZONE_RATIO


def tag_image(tag_id: int, px_per_cell: int = _PX_PER_CELL) -> np.ndarray:
    """The tag with its white quiet zone, (10 c, 10 c) uint8 grayscale, c = px_per_cell."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    if not (0 <= tag_id < dictionary.bytesList.shape[0]):
        raise RlgpError(f"tag36h11 id {tag_id} out of range 0..{dictionary.bytesList.shape[0] - 1}")
    black = cv2.aruco.generateImageMarker(dictionary, tag_id, _CELLS * px_per_cell)
    return cv2.copyMakeBorder(black, px_per_cell, px_per_cell, px_per_cell, px_per_cell,
                              cv2.BORDER_CONSTANT, value=255)


def _atomic_write(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp{path.suffix}")
    write(tmp)
    os.replace(tmp, path)


def tag_files(tag_id: int) -> tuple[Path, Path]:
    """(quad.obj, tag_<id>.png) in the cache, created if missing."""
    folder = cache_dir()
    obj = folder / "quad.obj"
    if not obj.exists():
        _atomic_write(obj, lambda p: p.write_text(_OBJ))
    png = folder / f"tag36h11_{tag_id:03d}_{_PX_PER_CELL}px.png"
    if not png.exists():
        img = cv2.cvtColor(tag_image(tag_id), cv2.COLOR_GRAY2BGR)

        def write(p: Path) -> None:
            if not cv2.imwrite(str(p), img):
                raise RlgpError(f"could not write {p}")

        _atomic_write(png, write)
    return obj, png
