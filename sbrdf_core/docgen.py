"""Reference pages generated from what is installed, never copied by hand.

The documentation site (``mkdocs.yml``, ``docs/hooks.py``) renders these at
build time: node kinds and every installed plugin's declared parameters
(the YAML graph reference), the artifact kinds' arrays, the contracts, the
BRDF models, and pages plugins contribute (the renderers' scene-file keys).
A third-party plugin appears here as soon as it is installed.
"""

from __future__ import annotations

from collections.abc import Sequence

from .params import Param

CATEGORY_TITLES = {
    "capture": "Capture sources (`Capture` nodes)",
    "registration": "Registration (`Register` nodes)",
    "fitter": "Fitters (`Fit` nodes)",
    "quantizer": "Quantizers (`Quantize` nodes)",
    "renderer": "Renderers (`Render` nodes)",
    "brdf-model": "BRDF models (`model:` of fitters, captures and scenes)",
    "device": "Devices (drivers and simulators)",
    "scene-effect": "Scene effects",
    "exporter": "Exporters (`Export` nodes)",
    "command": "Commands (`sbrdf <name>`)",
    "parameterization": "Parameterizations (separable BRDFs)",
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
        for spec in (registry.get(category, n) for n in sorted(specs)):
            src = f"{spec.distribution} {spec.version}".strip() or spec.plugin
            out += [f"### `{spec.name}`", "", f"{spec.summary}  ", f"_From {src}._", "", param_table(spec.params)]
    return "\n".join(out) + "\n"


def artifact_reference(registry=None) -> str:
    """Every artifact kind's arrays: the core's and those the loaded plugins declare."""
    from . import artifacts

    kinds = list(artifacts.KINDS.values())
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


def contracts_reference() -> str:
    """What each category's implementation provides (``sbrdf_core/contracts.py``), required and optional."""
    from . import contracts

    return "\n".join([
        "# Plugin contracts", "",
        "Generated from `sbrdf_core/contracts.py`: one `typing.Protocol` per contribution category. The registry "
        "checks an implementation against it on import and refuses one that lacks a required member; "
        "`sbrdf_core.testing` holds the behavioural suites ([plugin guide](../plugin-guide.md)).", "",
        contracts.contract_table(), "", "## Optional members", "",
        "The core asks for these only through `sbrdf_core.contracts.optional`, so each is listed here with what "
        "happens without it.", "", contracts.optional_table(), ""])


def model_reference(registry) -> str:
    """One section per installed BRDF model: its docstring, configuration and per-texel parameters."""
    import inspect

    out = ["# BRDF models", "",
           "Generated from each model's module docstring, configuration parameters and per-texel "
           "`ModelParameter` declarations (`sbrdf_core/docgen.py`).", ""]
    for name in registry.names("brdf-model"):
        spec = registry.get("brdf-model", name)
        impl = registry.load(spec)
        module = inspect.getmodule(impl)
        doc = inspect.getdoc(module) or inspect.getdoc(impl) or spec.summary
        out += [f"## `{name}`", "", doc, "", "### Configuration (`model_params`)", "", param_table(spec.params)]
        try:
            model = registry.create("brdf-model", name, {})
        except Exception:  # a model without defaults for every configuration parameter
            out.append("")
            continue
        rows = ["| parameter | channels | bounds | default | unit | meaning |", "|---|---|---|---|---|---|"]
        for p in model.parameters:
            rows.append(f"| `{p.name}` | {p.channels} | [{p.bounds[0]:g}, {p.bounds[1]:g}] | {p.default:g} | "
                        f"{_cell(p.unit)} | {_cell(p.doc)} |")
        out += ["### Per-texel parameters (default configuration)", "", "\n".join(rows), ""]
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
    out = {"reference/graph.md": graph_reference(registry), "reference/artifacts.md": artifact_reference(registry),
           "reference/hooks.md": hooks_reference(), "reference/contracts.md": contracts_reference(),
           "reference/models.md": model_reference(registry)}
    for contributed in registry.pm.hook.sbrdf_reference_pages(registry=registry):
        out.update(contributed or {})  # the scene-file reference comes from the renderers
    return out
