"""What the scene renderers (``cpu``, ``gl``) share as Render plugins: a scene file, its check and its fingerprint."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from sbrdf_core import contracts
from sbrdf_core.errors import SbrdfError
from sbrdf_core.params import Param
from sbrdf_core.types import RenderResult
from sbrdf_lib.mesh import load_mesh
from sbrdf_lib.scene import SceneError, load_scene, scene_fingerprint

from . import materials as mat
from .declarations import SCENE_RENDERER

if TYPE_CHECKING:
    from sbrdf_core.registry import Registry

logger = logging.getLogger(__name__)


def check_scene(params, registry=None) -> list[tuple[str, str]]:
    """``check_params`` of the scene renderers: everything a render would fail on that can be checked up front.

    The scene file and the scene effects it wants (:func:`effect_problems`),
    then what only a renderer knows how to read: every mesh is parsed with
    the mesh loader (:func:`sbrdf_lib.mesh.load_mesh`), and every uniform material (``model:`` with ``params:``)
    is constructed.  Stores named by ``artifact:`` or a plugin's store key
    (``shading_map:``) are opened at render time (another node may write them).
    """
    from sbrdf_core.registry import default_registry

    registry = registry if registry is not None else default_registry()
    try:
        scene = load_scene(params["scene"], registry=registry)
    except SceneError as e:
        return [("scene", "; ".join(str(p) for p in e.problems))]
    problems = [("scene", msg) for msg in effect_problems(scene, registry)]
    if problems:
        return problems
    out = []
    for o in scene.objects:
        if o.shape == "mesh" and "://" not in o.params["file"]:
            try:
                load_mesh(o.params["file"])
            except (SbrdfError, ImportError) as e:
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
            if ref.surface is None:
                mat.uniform(name, model, ref.params, ref.filter)
        except SbrdfError as e:
            msg = str(e)
            out.append(f"{scene.file}: " + (msg if msg.startswith(f"material {name!r}") else f"material {name!r}: {msg}"))
    return [("scene", m) for m in out]


def effect_problems(scene, registry) -> list[str]:
    """What would stop a renderer constructing the scene's effects, found without rendering.

    Every installed scene effect the scene wants is constructed from its
    options (a constructor only stores and checks them); one that defines
    ``check(scene) -> [message]`` then checks what it will read (an
    environment map's file).  Effects named in ``effects:`` that no plugin
    provides are reported too; keys of a plugin that is not installed are
    already unknown to the scene loader.
    """
    out: list[str] = []
    provided: set[str] = set()
    for name in registry.names("scene-effect"):
        try:
            cls = registry.load(registry.get("scene-effect", name))
            if not cls.wanted(scene):
                continue
            provided.add(name)
            effect = registry.create("scene-effect", name, cls.options(scene))
            check = contracts.optional(effect, "check", "scene-effect")
            out += [f"{scene.file}: scene effect {name!r}: {m}" for m in (check(scene) if callable(check) else [])]
        except SbrdfError as e:
            msg = str(e)
            out.append(f"{scene.file}: " + (msg if msg.startswith("scene-effect ") else f"scene effect {name!r}: {msg}"))
    missing = sorted(set(scene.effects) - provided)
    if missing:
        out.append(f"{scene.file}: effects: no installed scene effect provides {missing} "
                   "(see `sbrdf plugins --category scene-effect`)")
    return out


class SceneRenderer:
    """Base of Render plugins that draw a scene file; subclasses implement ``render``."""

    params: tuple[Param, ...] = SCENE_RENDERER  # a subclass adds its own

    def __init__(self, *, scene: str, exposure: float | None = None):
        self.scene_path, self.exposure = scene, exposure
        self.registry: Registry | None = None

    def bind(self, registry: Registry) -> None:
        self.registry = registry

    @staticmethod
    def check_params(params, registry=None) -> list[tuple[str, str]]:
        """The scene file, its effects, meshes and uniform materials, checked when the graph is validated."""
        return check_scene(params, registry)

    def fingerprint(self) -> str:
        return scene_fingerprint(self.scene_path, self.registry)

    def prepare(self, material) -> dict:
        """The parameter maps of the scene's store-backed materials, lazy: the runner computes them before build."""
        scene = load_scene(self.scene_path, registry=self.registry)
        return mat.prepare(scene, material, self._registry())

    def load(self, material, prepared: dict | None = None):
        """The scene and its resolved materials (``material``: the Render node's input; ``prepared``: see above)."""
        scene = load_scene(self.scene_path, registry=self.registry)
        return scene, mat.resolve(scene, material, self._registry(), prepared)

    def _registry(self) -> Registry:
        if self.registry is None:
            from sbrdf_core.registry import default_registry

            self.registry = default_registry()
        return self.registry

    def result(self, scene, image, attrs: dict) -> RenderResult:
        exposure = self.exposure if self.exposure is not None else scene.exposure
        return RenderResult(image, exposure, {"scene": self.scene_path, **attrs}, scene.gamma)
