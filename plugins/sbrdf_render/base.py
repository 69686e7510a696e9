"""What the scene renderers (``cpu``, ``gl``) share as Render plugins: a scene file, its check and its fingerprint."""

from __future__ import annotations

from sbrdf_core.nodes.render import RenderResult
from sbrdf_core.scene import check_scene_param, load_scene, scene_fingerprint

from . import materials as mat


class SceneRenderer:
    """Base of Render plugins that draw a scene file; subclasses implement ``render``."""

    def __init__(self, scene: str, exposure: float | None = None):
        self.scene_path, self.exposure = scene, exposure
        self.registry = None

    def bind(self, registry) -> None:
        self.registry = registry

    check_params = staticmethod(check_scene_param)

    def fingerprint(self) -> str:
        return scene_fingerprint(self.scene_path)

    def load(self, material):
        """The scene and its resolved materials (``material``: the Render node's input)."""
        scene = load_scene(self.scene_path)
        return scene, mat.resolve(scene, material, self.registry)

    def result(self, scene, image, attrs: dict) -> RenderResult:
        exposure = self.exposure if self.exposure is not None else scene.exposure
        return RenderResult(image, exposure, {"scene": self.scene_path, **attrs}, scene.gamma)
