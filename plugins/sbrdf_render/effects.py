"""The scene effects (``sbrdf_scene_effects`` plugins) a scene calls for, constructed for one render.

Both renderers ask :func:`active_effects` and run only what it returns;
the protocol is documented on :func:`sbrdf_core.hookspecs.sbrdf_scene_effects`.
"""

from __future__ import annotations

import logging

from sbrdf_core.errors import SbrdfError

logger = logging.getLogger(__name__)


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
        logger.debug("scene effect %r prepared for %s", name, scene.file)
        out.append(effect)
    return out


def check_covered(scene, effects) -> None:
    """An error when the scene names an effect no installed plugin provides (rather than ignoring it).

    Keys that call for a plugin's effect (``environment:``, ``reflector:``) come from that plugin's
    ``sbrdf_scene_keys``, so without the plugin the scene loader already refuses them.
    """
    missing = sorted(set(scene.effects) - {getattr(e, "name", "") for e in effects})
    if missing:
        raise SbrdfError(f"{scene.file}: effects: no installed scene effect provides {missing} (see `sbrdf plugins "
                         "--category scene-effect`)")
