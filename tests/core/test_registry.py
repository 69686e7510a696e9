"""Plugin discovery through the ``sbrdf`` entry-point group, validation, isolation, laziness."""

from __future__ import annotations

import ast
import subprocess
import sys
import types
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

from sbrdf_core.errors import PluginError
from sbrdf_core.plugin import PluginSpec, hookimpl
from sbrdf_core.registry import PluginLoadWarning, Registry

ROOT = Path(__file__).resolve().parents[2]


def ep(name: str, value: str) -> EntryPoint:
    return EntryPoint(name=name, value=value, group="sbrdf")


def module(name: str, **hooks) -> types.ModuleType:
    mod = types.ModuleType(name)
    for k, v in hooks.items():
        setattr(mod, k, hookimpl(v))
    sys.modules[name] = mod
    return mod


def test_builtins_come_through_the_installed_entry_points():
    from importlib.metadata import entry_points

    names = {e.name: e.value for e in entry_points(group="sbrdf")}
    for pkg in ("sbrdf_models", "sbrdf_capture", "sbrdf_register", "sbrdf_fitters", "sbrdf_quantizers",
                "sbrdf_render"):
        assert pkg in names.values()  # one entry point per package, the BRDF models' included
    assert not [v for v in names.values() if v.startswith("sbrdf_models.")]
    reg = Registry()
    assert reg.get("brdf-model", "lambert").distribution == "sbrdf"
    assert reg.get("fitter", "lm").plugin == "fitters"


def test_every_builtin_plugin_package_is_an_entry_point():
    """A package under ``plugins/`` is named once, by its entry point; packaging finds it by its ``sbrdf_`` prefix."""
    from importlib.metadata import entry_points

    named = {e.value.split(".")[0].partition(":")[0] for e in entry_points(group="sbrdf")}
    packages = {p.name for p in (ROOT / "plugins").iterdir() if (p / "__init__.py").exists()}
    assert packages <= named, f"plugin packages without an entry point: {sorted(packages - named)}"
    assert all(p.startswith("sbrdf_") for p in packages)


def test_discovery_from_hand_built_entry_points():
    module("fake_plugin_a", sbrdf_brdf_models=lambda: [PluginSpec("fake-model", "sbrdf_models.lambert:LambertModel")])
    reg = Registry(entry_points_=[ep("a", "fake_plugin_a")])
    assert reg.names("brdf-model") == ["fake-model"]  # only what the entry points gave
    assert set(reg.node_kinds) == {"Capture", "Register", "Reflectance", "Fit", "Quantize", "Render", "Export"}


def test_broken_plugin_warns_and_others_still_load():
    module("fake_plugin_ok", sbrdf_fitters=lambda: [PluginSpec("ok-fit", "sbrdf_fitters.lm:LevenbergMarquardtFitter")])
    with pytest.warns(PluginLoadWarning, match="'broken'.*no_such_module_xyz"):
        reg = Registry(entry_points_=[ep("broken", "no_such_module_xyz"), ep("ok", "fake_plugin_ok")])
    assert "ok-fit" in reg.names("fitter")
    assert "broken" in reg.failed


def test_duplicate_name_is_an_error_naming_both():
    module("fake_dup_1", sbrdf_quantizers=lambda: [PluginSpec("same", "x.y:Z")])
    module("fake_dup_2", sbrdf_quantizers=lambda: [PluginSpec("same", "x.y:W")])
    with pytest.raises(PluginError, match=r"quantizer 'same' is contributed twice.*fake_1.*fake_2"):
        Registry(entry_points_=[ep("fake_1", "fake_dup_1"), ep("fake_2", "fake_dup_2")])


def test_hook_with_unknown_argument_is_rejected():
    def sbrdf_fitters(bogus):
        return []

    module("fake_badsig", sbrdf_fitters=sbrdf_fitters)
    with pytest.raises(PluginError, match="fake_bad.*invalid"):
        Registry(entry_points_=[ep("fake_bad", "fake_badsig")])


def test_disable_by_name_but_not_essential(monkeypatch):
    reg = Registry(disabled=["render"])
    assert reg.names("renderer") == []
    monkeypatch.setenv("SBRDF_DISABLE_PLUGINS", "fitters,lm-gl,tables,separable,sbrdf_core.nodes")
    reg = Registry()
    assert reg.names("fitter") == [] and "Fit" in reg.node_kinds


def test_unknown_name_lists_installed():
    reg = Registry()
    assert {"lm", "lm-gl", "mcallister", "line-search"} <= set(reg.names("fitter"))
    with pytest.raises(PluginError, match="unknown fitter plugin 'nope'; installed: " + ", ".join(reg.names("fitter")) + "$"):
        reg.get("fitter", "nope")


def test_spec_validates_its_own_declaration():
    with pytest.raises(ValueError, match="lowercase-hyphenated"):
        PluginSpec("Bad_Name", "a.b:C")
    with pytest.raises(ValueError, match="package.module:Class"):
        PluginSpec("ok", "no-colon")


#: What listing plugins or validating a graph must not import: the storage and compute engines, the compiler,
#: SciPy, OpenCV, GL and plotting come in only when a run (or a command that draws) needs them.  (pyserial is
#: still imported by the rig's drivers when ``sbrdf plugins`` reads their parameters.)
HEAVY = ("zarr", "fsspec", "numba", "scipy", "dask", "cv2", "moderngl", "OpenEXR", "distributed", "matplotlib")


def _heavy_after(command: list[str]) -> list[str]:
    code = (
        "import contextlib, io, sys; from sbrdf_core.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    rc = main({command!r})\n"
        f"print(rc, [m for m in {HEAVY!r} if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    rc, heavy = out.stdout.strip().splitlines()[-1].split(" ", 1)
    assert rc == "0", out.stdout + out.stderr
    return ast.literal_eval(heavy)


def test_registry_names_import_no_heavy_module():
    code = (
        "import sys; from sbrdf_core.registry import Registry; r = Registry(); "
        "[r.names(c) for c in r.specs]; "
        f"heavy = [m for m in {HEAVY + ('serial',)!r} if m in sys.modules]; "
        "print(heavy); sys.exit(1 if heavy else 0)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_listing_plugins_imports_no_heavy_module():
    """``sbrdf plugins`` imports every implementation to read its parameters: none may import heavy code at
    module level."""
    assert _heavy_after(["plugins"]) == []


def test_listing_imports_no_implementation_whose_spec_declares_its_parameters():
    """A spec that carries its parameters (the plugin's light declarations) is listed from them: ``sbrdf plugins``
    imports none of those implementations (npe2's manifest, read without running plugin code)."""
    code = (
        "import contextlib, io, sys; from sbrdf_core.registry import Registry; from sbrdf_core.cli import main\n"
        "declared = sorted({s.impl.partition(':')[0] for specs in Registry().specs.values() for s in specs.values()\n"
        "                   if s.params is not None})\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    main(['plugins'])\n"
        "print(len(declared), [m for m in declared if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    n, imported = out.stdout.strip().splitlines()[-1].split(" ", 1)
    assert int(n) > 0
    assert ast.literal_eval(imported) == []


def test_validating_a_graph_imports_no_heavy_module():
    assert _heavy_after(["validate", "graphs/virtual-scan.yaml"]) == []


def test_core_never_imports_plugins():
    builtin = {p.name for p in (ROOT / "plugins").iterdir() if p.is_dir() and not p.name.startswith("_")}
    for path in (ROOT / "sbrdf_core").rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            for n in names:
                assert n.split(".")[0] not in builtin | {"plugins"}, f"{path} imports plugin {n}"
