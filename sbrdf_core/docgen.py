"""Reference pages generated from what is installed, never copied by hand.

The documentation site (``mkdocs.yml``, ``docs/hooks.py``) renders these at
build time: node kinds and every installed plugin's declared parameters
(the YAML graph reference), the artifact kinds' arrays, and the scene-file
keys.  A third-party plugin appears here as soon as it is installed.
"""

from __future__ import annotations

from collections.abc import Sequence

from .params import Param

CATEGORY_TITLES = {
    "capture": "Capture sources (`Capture` nodes)",
    "register": "Registration (`Register` nodes)",
    "fitter": "Fitters (`Fit` nodes)",
    "quantizer": "Quantizers (`Quantize` nodes)",
    "renderer": "Renderers (`Render` nodes)",
    "brdf-model": "BRDF models (`model:` of fitters, captures and scenes)",
    "device": "Devices (drivers and simulators)",
    "scene-effect": "Scene effects",
}


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def param_table(params: Sequence[Param]) -> str:
    """A Markdown table of declared parameters."""
    if not params:
        return "_No parameters._\n"
    rows = ["| parameter | type | default | meaning |", "|---|---|---|---|"]
    for p in params:
        t = f"list[{p.item}]" if p.type == "list" and p.item else p.type
        if p.length:
            t += f"[{p.length}]"
        if p.unit:
            t += f" ({p.unit})"
        d = "**required**" if p.required else f"`{p.default!r}`"
        extra = []
        if p.choices:
            extra.append("one of " + ", ".join(f"`{c}`" for c in p.choices))
        if p.bounds:
            extra.append(f"in [{p.bounds[0]}, {p.bounds[1]}]")
        doc = p.doc + (f" ({'; '.join(extra)})" if extra else "")
        rows.append(f"| `{p.name}` | {_cell(t)} | {_cell(d)} | {_cell(doc)} |")
    return "\n".join(rows) + "\n"


def graph_reference(registry) -> str:
    """Node kinds, then every plugin category with each plugin's parameters."""
    out = ["# YAML graph reference", "",
           "Generated from the installed plugins' declarations when the documentation is built "
           "(`sbrdf_core/docgen.py`); `sbrdf plugins` prints the same on the command line. A graph names a "
           "node `kind`, its `plugin` and the plugin's `params` ([graphs and runs](../graphs.md)).", "",
           "## Node kinds", "",
           "| kind | inputs | output | plugin category |", "|---|---|---|---|"]
    for name, kind in registry.node_kinds.items():
        ins = "<br>".join(f"`{p.name}`: {p.kind_names}" + (" (optional)" if p.optional else "")
                          for p in kind.inputs) or "-"
        out.append(f"| `{name}` | {ins} | `{kind.output.kind}` | {kind.plugin_category or '-'} |")
    out.append("")
    for name, kind in registry.node_kinds.items():
        if kind.params:
            out += [f"### `{name}` node parameters", "", param_table(kind.params)]
    for category, specs in registry.specs.items():
        if not specs:
            continue
        out += [f"## {CATEGORY_TITLES.get(category, category)}", ""]
        for spec in sorted(specs.values(), key=lambda s: s.name):
            src = f"{spec.distribution} {spec.version}".strip() or spec.plugin
            out += [f"### `{spec.name}`", "", f"{spec.summary}  ", f"_From {src}._", "", param_table(spec.params)]
    return "\n".join(out) + "\n"


def artifact_reference() -> str:
    """Every artifact kind's arrays."""
    from . import artifacts

    kinds = [v for v in vars(artifacts).values() if isinstance(v, artifacts.ArtifactKind)]
    out = ["# Artifact reference", "",
           "Every artifact is a zarr group with `kind`, `version` and provenance attributes "
           "([graphs and runs](../graphs.md)). Dimension letters: P poses, H×W image pixels, V×U texels "
           "(v along +y, u along +x of the sample), C colour or parameter channels, K texture channels. "
           "Generated from `sbrdf_core/artifacts.py`; plugins may add kinds of their own.", ""]
    for k in kinds:
        out += [f"## `{k.kind}` (version {k.version})", "", k.doc, "",
                "| array | dims | dtype | meaning |", "|---|---|---|---|"]
        for a in k.arrays:
            flags = [] if a.required else ["optional"]
            if a.timing:
                flags.append("timing")
            out.append(f"| `{a.name}` | {a.dims} | {a.dtype} | {_cell(a.doc)}{' (' + ', '.join(flags) + ')' if flags else ''} |")
        out.append("")
    return "\n".join(out) + "\n"


def scene_reference() -> str:
    """Every key of a scene file."""
    from . import scene as sc

    out = ["# Scene-file reference", "",
           "Generated from `sbrdf_core/scene.py`; see [scenes and renderers](../scenes.md) for conventions.", "",
           "## `camera`", "", param_table(sc.CAMERA),
           "## `materials: {name: ...}`", "", param_table(sc.MATERIAL),
           "## `objects: [...]`", "", "Every object:", "", param_table(sc._OBJECT_COMMON)]
    for shape, params in sc.SHAPES.items():
        out += [f"`shape: {shape}`:", "", param_table(params)]
    out += ["### `transform`", "", param_table(sc.TRANSFORM), "## `lights: [...]`", ""]
    for kind, params in sc.LIGHTS.items():
        out += [f"`type: {kind}`:", "", param_table(params)]
    out += ["## `environment`", "", param_table(sc.ENVIRONMENT), "## `display`", "", param_table(sc.DISPLAY),
            "## Other keys", "", "`shadows` (bool, default false), `background` (a number or an RGB triple), "
            "`effects` (scene-effect name -> its options, for effects that plugins add, e.g. "
            "`{ambient: {radiance: 0.1}}`).", ""]
    return "\n".join(out) + "\n"


def hooks_reference() -> str:
    """Every hook of the plugin contract, with its docstring (``sbrdf_core/hookspecs.py``)."""
    import inspect

    from . import hookspecs

    out = ["# Plugin hooks", "", inspect.getdoc(hookspecs) or "", ""]
    for name, fn in vars(hookspecs).items():
        if name.startswith("sbrdf_") and callable(fn):
            out += [f"## `{name}{inspect.signature(fn)}`", "", "```text", inspect.getdoc(fn) or "", "```", ""]
    return "\n".join(out) + "\n"


def pages(registry) -> dict[str, str]:
    """``{path under docs/: markdown}`` of every generated page."""
    return {"reference/graph.md": graph_reference(registry), "reference/artifacts.md": artifact_reference(),
            "reference/scene.md": scene_reference(), "reference/hooks.md": hooks_reference()}
