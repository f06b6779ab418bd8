"""Which tag belongs to which object: built from a scene's ``[object.tag]`` entries."""

from __future__ import annotations

from dataclasses import dataclass

from rlgp_exec.perception.camera import FloatArray, PerceptionError
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import T_object_tag

__all__ = ["TagMount", "TagRegistry"]


@dataclass(frozen=True)
class TagMount:
    """A tag on an object: its black-square edge [m] and T_object_tag (4, 4)."""

    tag_id: int
    object: str
    size: float
    T_object_tag: FloatArray


class TagRegistry:
    """tag id -> :class:`TagMount`; several tags may share an object, an id belongs to one object."""

    def __init__(self, mounts: list[TagMount]) -> None:
        self._by_id: dict[int, TagMount] = {}
        for m in mounts:
            if m.tag_id in self._by_id:
                raise PerceptionError(f"tag id {m.tag_id} is on both {self._by_id[m.tag_id].object!r} and {m.object!r}")
            if not (m.size > 0.0):
                raise PerceptionError(f"tag {m.tag_id} on {m.object!r}: size must be > 0 m, got {m.size}")
            self._by_id[m.tag_id] = m

    @classmethod
    def from_scene(cls, scene: Scene) -> TagRegistry:
        return cls(
            [TagMount(o.tag.id, o.name, o.tag.size, T_object_tag(o)) for o in scene.objects if o.tag is not None]
        )

    def get(self, tag_id: int) -> TagMount | None:
        return self._by_id.get(tag_id)

    @property
    def ids(self) -> list[int]:
        return sorted(self._by_id)

    @property
    def objects(self) -> list[str]:
        return sorted({m.object for m in self._by_id.values()})

    def __len__(self) -> int:
        return len(self._by_id)
