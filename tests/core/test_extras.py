"""A missing optional dependency becomes one clear message naming the extra that installs it."""

from __future__ import annotations

import sys

import pytest

from sbrdf_core.errors import PluginError, SbrdfError
from sbrdf_core.extras import EXTRAS, MissingExtra, require


def test_require_imports_what_is_there():
    assert require("json").__name__ == "json"


def test_a_missing_module_names_its_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "moderngl", None)  # as if not installed
    with pytest.raises(MissingExtra) as e:
        require("moderngl", feature="the gl renderer")
    assert isinstance(e.value, PluginError) and isinstance(e.value, SbrdfError) and isinstance(e.value, ImportError)
    assert e.value.extra == "gl" == EXTRAS["moderngl"][0]
    assert str(e.value) == ("the gl renderer needs the optional dependency 'moderngl', which is not installed: "
                            "pip install 'sbrdf[gl]'")


def test_a_module_that_fails_inside_is_not_reported_as_missing(tmp_path, monkeypatch):
    (tmp_path / "broken_dep_mod.py").write_text("import no_such_inner_module_xyz\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModuleNotFoundError) as e:
        require("broken_dep_mod", extra="gl")
    assert not isinstance(e.value, MissingExtra)


def test_extras_are_declared_in_pyproject():
    import tomllib
    from pathlib import Path

    meta = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())["project"]
    extras = meta["optional-dependencies"]
    for module, (extra, dist) in EXTRAS.items():
        assert any(dep.startswith(dist) for dep in extras[extra]), (module, extra)
        assert not any(dep.startswith(dist) for dep in meta["dependencies"]), f"{dist} is both required and an extra"
