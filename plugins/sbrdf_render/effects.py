"""The scene effects (``sbrdf_scene_effects`` plugins) a scene calls for, constructed for one render.

Both renderers ask :func:`active_effects` and run only what it returns;
the protocol is documented on :func:`sbrdf_core.hookspecs.sbrdf_scene_effects`.
"""

from __future__ import annotations

from sbrdf_core.errors import SbrdfError


def active_effects(scene, materials: dict, registry=None, gl_context=None) -> list:
    """Every installed scene effect that ``scene`` wants, constructed from its options and prepared."""
    from sbrdf_core.registry import default_registry

    registry = registry if registry is not None else default_registry()
    out = []
    for name in registry.names("scene-effect"):
        cls = registry.load(registry.get("scene-effect", name))
        if not cls.wanted(scene):
            continue
        try:
            effect = registry.create("scene-effect", name, cls.options(scene))
        except SbrdfError as e:
            raise SbrdfError(f"{scene.file}: scene effect {name!r}: {e}") from None
        effect.prepare(scene, materials, gl_context)
        out.append(effect)
    return out


def check_covered(scene, effects) -> None:
    """An error when the scene needs an effect no installed plugin provides (rather than ignoring it)."""
    if scene.environment is not None and not any(getattr(e, "name", "") == "environment" for e in effects):
        raise SbrdfError(f"{scene.file}: environment lighting needs the environment scene effect (plugin "
                         "sbrdf_envmap), which is not installed")
    if any(o.params.get("reflector") for o in scene.objects) and not any(getattr(e, "name", "") == "mirror"
                                                                       for e in effects):
        raise SbrdfError(f"{scene.file}: reflector: true needs the mirror scene effect (plugin sbrdf_envmap), which "
                         "is not installed")
    missing = sorted(set(scene.effects) - {getattr(e, "name", "") for e in effects})
    if missing:
        raise SbrdfError(f"{scene.file}: effects: no installed scene effect provides {missing} (see `sbrdf plugins "
                         "--category scene-effect`)")
