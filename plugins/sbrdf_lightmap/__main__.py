"""``python -m sbrdf_lightmap SCENE``: bake a scene's light maps into its lightmap: directory."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    from sbrdf_core.registry import default_registry

    from .node import bake_scene

    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    _, stats, scene = bake_scene(default_registry(), args[0])
    print(f"lightmap: {len(stats['maps'])} maps in {scene.lightmap.directory} ({stats['bake_s']:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
