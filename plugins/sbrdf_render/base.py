"""What the scene renderers (``cpu``, ``gl``) share as Render plugins: a scene file, its check and its fingerprint."""

from __future__ import annotations

from sbrdf_core.nodes.render import RenderResult
from sbrdf_core.scene import check_scene_param, load_scene, scene_fingerprint

from . import materials as mat


def check_scene(params, registry=None) -> list[tuple[str, str]]:
    """``check_params`` of the scene renderers: everything a render would fail on that can be checked up front.

    The scene file and its effects (:func:`sbrdf_core.scene.check_scene_param`),
    then what only a renderer knows how to read: every mesh is parsed with
    the renderer's OBJ loader, and every uniform material (``model:`` with
    ``params:``) is constructed.  Stores named by ``artifact:`` or
    ``shading_map:`` are opened at render time (another node may write them).
    """
    from sbrdf_core.errors import SbrdfError
    from sbrdf_core.registry import default_registry

    from .shapes import load_obj

    registry = registry if registry is not None else default_registry()
    problems = check_scene_param(params, registry)
    if problems:
        return problems
    scene = load_scene(params["scene"])
    out = []
    for o in scene.objects:
        if o.shape == "mesh" and "://" not in o.params["file"]:
            try:
                load_obj(o.params["file"])
            except SbrdfError as e:
                out.append(f"{scene.file}:{o.line}: mesh: {e}")
            except UnicodeDecodeError as e:
                out.append(f"{scene.file}:{o.line}: mesh: {o.params['file']}: not a UTF-8 OBJ file (byte "
                           f"0x{e.object[e.start]:02x} at offset {e.start})")
    for name in sorted({o.material for o in scene.objects}):
        ref = scene.materials.get(name)
        if ref is None or ref.model is None:
            continue
        try:
            model = registry.create("brdf-model", ref.model, dict(ref.model_params))
            if ref.shading is None:
                mat.uniform(name, model, ref.params, ref.filter)
        except SbrdfError as e:
            msg = str(e)
            out.append(f"{scene.file}: " + (msg if msg.startswith(f"material {name!r}") else f"material {name!r}: {msg}"))
    return [("scene", m) for m in out]


class SceneRenderer:
    """Base of Render plugins that draw a scene file; subclasses implement ``render``."""

    def __init__(self, scene: str, exposure: float | None = None):
        self.scene_path, self.exposure = scene, exposure
        self.registry = None

    def bind(self, registry) -> None:
        self.registry = registry

    @staticmethod
    def check_params(params, registry=None) -> list[tuple[str, str]]:
        """The scene file, its effects, meshes and uniform materials, checked when the graph is validated."""
        return check_scene(params, registry)

    def fingerprint(self) -> str:
        return scene_fingerprint(self.scene_path)

    def load(self, material):
        """The scene and its resolved materials (``material``: the Render node's input)."""
        scene = load_scene(self.scene_path)
        return scene, mat.resolve(scene, material, self.registry)

    def result(self, scene, image, attrs: dict) -> RenderResult:
        exposure = self.exposure if self.exposure is not None else scene.exposure
        return RenderResult(image, exposure, {"scene": self.scene_path, **attrs}, scene.gamma)
