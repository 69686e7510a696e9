"""Parameter declarations: one tuple of :class:`Param` per plugin.

A plugin declares its parameters once, as data.  The same tuple validates YAML
graphs (an unknown name gets an error listing the accepted ones), fills in
defaults, feeds ``sbrdf plugins`` and the generated docs, and is the signature
its implementation is constructed with.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .errors import ParameterError


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


#: Marker default for a parameter the graph must give.
REQUIRED: Any = _Required()

_TYPE_NAMES = {
    "int": "int",
    "float": "float",
    "str": "str",
    "bool": "bool",
    "list": "list",
    "dict": "dict",
    "any": "any",
}


@dataclass(frozen=True)
class Param:
    """One declared plugin parameter.

    Parameters
    ----------
    name
        The key used in YAML ``params:``.
    type
        One of ``int``, ``float``, ``str``, ``bool``, ``list``, ``dict``, ``any``.
    default
        Value used when the graph omits it; :data:`REQUIRED` if it must be given.
    doc
        One sentence for ``sbrdf plugins`` and the reference docs.
    choices
        Allowed values, if the parameter is an enumeration.
    bounds
        Inclusive ``(low, high)`` for numbers (either may be ``None``).
    length
        Required length for ``list`` parameters (e.g. 2 for ``[width, height]``).
    item
        Element type for ``list`` parameters (``int``, ``float``, ``str``).
    unit
        Unit of the value (``mm``, ``s``, ``sr^-1``), shown in docs.
    nullable
        Whether ``null`` is accepted (meaning "not set").
    extra
        Free-form flags read by the validator and tools: ``path`` (a file
        name, resolved from the graph or scene file's folder), ``output``
        (with ``path``: a path the plugin *writes*, held inside the graph's
        store beside the artifacts unless the graph's ``allow_outside_store``
        lets it out: :mod:`sbrdf_core.outputs`), ``plugin_category`` (the
        value names a plugin of that category), ``params_of`` (the value is
        the parameters of the plugin another parameter names); the validator
        (:mod:`sbrdf_core.graph`) reads the rest.
    schema
        For a ``dict`` with fixed keys: the declaration of each key.  Unknown
        keys and missing required ones are errors naming the path
        (``camera.exposure_s``).  The value is checked, not rewritten: defaults
        of a sub-schema are documentation and the plugin's own fallbacks, so a
        graph's resolved parameters (and its cache tokens) stay as written.
    values
        For a ``dict`` mapping free names to dicts (``motors: {arm: {...}}``):
        the schema every value follows.
    nonfinite
        Whether NaN and ±infinity are accepted (in the value and, for ``list``,
        ``dict`` and ``any``, anywhere inside it).  Off by default: YAML's
        ``.nan``, ``.inf`` and an overflowing ``1e400`` are refused with the
        parameter named, since a bounds check cannot catch them (``nan < lo``
        is false).
    """

    name: str
    type: str
    default: Any = REQUIRED
    doc: str = ""
    choices: tuple | None = None
    bounds: tuple[float | None, float | None] | None = None
    length: int | None = None
    item: str | None = None
    unit: str = ""
    nullable: bool = False
    extra: Mapping[str, Any] = field(default_factory=dict)
    nonfinite: bool = False
    schema: tuple[Param, ...] | None = None
    values: tuple[Param, ...] | None = None

    def __post_init__(self) -> None:
        if self.type not in _TYPE_NAMES:
            raise ValueError(f"Param {self.name!r}: unknown type {self.type!r}; use one of {sorted(_TYPE_NAMES)}")
        if (self.schema is not None or self.values is not None) and self.type != "dict":
            raise ValueError(f"Param {self.name!r}: schema/values need type 'dict', not {self.type!r}")

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    def describe(self) -> str:
        """``name: type = default`` as shown in error messages and listings."""
        t = f"list[{self.item}]" if self.type == "list" and self.item else self.type
        if self.length:
            t += f"[{self.length}]"
        d = "required" if self.required else f"default {self.default!r}"
        extra = ""
        if self.choices:
            extra = f", one of {list(self.choices)}"
        if self.bounds:
            extra += f", in [{self.bounds[0]}, {self.bounds[1]}]"
        unit = f" {self.unit}" if self.unit else ""
        return f"{self.name} ({t}{unit}, {d}{extra})"

    def check(self, value: Any) -> Any:
        """Return ``value`` coerced to the declared type, or raise :class:`ParameterError`."""
        if value is None:
            if self.nullable or self.default is None:
                return None
            raise ParameterError(f"parameter {self.name!r} may not be null; expected {self.describe()}")
        value = _coerce(self.type, value, self.name)
        if self.type == "list":
            if self.length is not None and len(value) != self.length:
                raise ParameterError(f"parameter {self.name!r} needs {self.length} items, got {len(value)}")
            if self.item:
                value = [_coerce(self.item, v, f"{self.name}[{i}]") for i, v in enumerate(value)]
        if not self.nonfinite:
            bad = _nonfinite(value)
            if bad is not None:
                where = f" (at {self.name}{bad[0]})" if bad[0] else ""
                raise ParameterError(f"parameter {self.name!r} is not a finite number{where}: {bad[1]!r}; "
                                     "NaN and infinity are not accepted here")
        if self.schema is not None:
            _check_keys(self.schema, value, self.name)
        if self.values is not None:
            for key, sub in value.items():
                if not isinstance(sub, Mapping):
                    raise ParameterError(f"parameter {self.name}.{key} should be a mapping of "
                                         f"{', '.join(p.name for p in self.values)}; got {sub!r}")
                _check_keys(self.values, sub, f"{self.name}.{key}")
        if self.choices is not None and value not in self.choices:
            raise ParameterError(f"parameter {self.name!r} is {_short(value)}; expected one of {list(self.choices)}")
        if self.bounds is not None:
            items = value if self.type == "list" else [value]
            lo, hi = self.bounds
            for v in items:
                if (lo is not None and v < lo) or (hi is not None and v > hi):
                    raise ParameterError(f"parameter {self.name!r} = {_short(v)} is outside [{lo}, {hi}]")
        return value


def _check_keys(schema: Sequence[Param], value: Mapping[str, Any], path: str) -> None:
    """Check a nested mapping against its declared keys, naming the full path of what is wrong."""
    by_name = {p.name: p for p in schema}
    for key in value:
        if key not in by_name:
            raise ParameterError(f"unknown key {path}.{key}; accepted: {', '.join(by_name)}")
    for p in schema:
        if p.name in value:
            replace_name(p, f"{path}.{p.name}").check(value[p.name])
        elif p.required:
            raise ParameterError(f"parameter {path}.{p.name} is required: {p.describe()}")


def replace_name(p: Param, name: str) -> Param:
    from dataclasses import replace

    return replace(p, name=name)


def _nonfinite(value: Any, where: str = "", depth: int = 0) -> tuple[str, float] | None:
    """The first NaN or infinity in ``value`` (a number, or inside lists and mappings) as ``(where, value)``."""
    if isinstance(value, numbers.Real) and not isinstance(value, (bool, numbers.Integral)):
        return None if math.isfinite(value) else (where, float(value))
    if depth > 64:
        return None
    if isinstance(value, Mapping):
        items = ((f"{where}.{k}", v) for k, v in value.items())
    elif isinstance(value, Sequence) and not isinstance(value, (str, bytes)):
        items = ((f"{where}[{i}]", v) for i, v in enumerate(value))
    else:
        return None
    for w, v in items:
        bad = _nonfinite(v, w, depth + 1)
        if bad is not None:
            return bad
    return None


#: Integers a parameter may hold: numpy's int64, what every array, seed and size is made of.
INT_RANGE = (-(2**63), 2**63 - 1)


def _short(value: Any) -> str:
    """``repr(value)``, shortened: a 5000-digit integer in an error message helps nobody."""
    if isinstance(value, numbers.Integral) and abs(int(value)) >= 10**40:
        try:
            return f"an integer of {len(str(abs(int(value))))} digits"
        except ValueError:  # more digits than Python converts to text
            return f"an integer of about {int(int(value).bit_length() * 0.30103)} digits"
    text = repr(value)
    return text if len(text) <= 200 else text[:200] + "..."


_YAML11_FLOAT = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+$")


def _coerce(type_: str, value: Any, name: str) -> Any:
    if type_ == "float" and isinstance(value, str) and _YAML11_FLOAT.match(value):
        value = float(value)  # PyYAML (YAML 1.1) reads 1e-3 as a string; YAML 1.2 and users mean a number
    ok = {
        "int": isinstance(value, numbers.Integral) and not isinstance(value, bool),
        "float": isinstance(value, numbers.Real) and not isinstance(value, bool),
        "str": isinstance(value, str),
        "bool": isinstance(value, bool),
        "list": isinstance(value, Sequence) and not isinstance(value, str),
        "dict": isinstance(value, Mapping),
        "any": True,
    }[type_]
    if not ok:
        raise ParameterError(f"parameter {name!r} should be {type_}, got {type(value).__name__} {_short(value)}")
    if type_ == "float":
        try:
            return float(value)
        except OverflowError:  # an integer literal beyond the largest float (about 1.8e308)
            raise ParameterError(f"parameter {name!r} = {_short(value)} is too large for a float") from None
    if type_ == "int":
        if not INT_RANGE[0] <= value <= INT_RANGE[1]:  # arrays, seeds and sizes downstream are 64-bit
            raise ParameterError(f"parameter {name!r} = {_short(value)} does not fit in a 64-bit integer")
        return int(value)
    if type_ == "list":
        return list(value)
    if type_ == "dict":
        return dict(value)
    return value


def check_model_values(model: Any, values: Mapping[Any, Any], where: str = "params") -> list[tuple[Any, str]]:
    """Problems of ``values``, a mapping of a BRDF model's parameter name to a value, as ``(key, message)``.

    Each name must be one of the model's parameters (its ``parameters``
    declarations), each value a number or a list of one number per channel
    (or a single number for all), finite, inside the parameter's ``bounds``
    (the physically valid range the fitters enforce).
    """
    declared = {p.name: p for p in getattr(model, "parameters", ())}
    problems: list[tuple[Any, str]] = []
    for key, value in values.items():
        p = declared.get(key)
        if p is None:
            problems.append((key, f"{where}.{key}: model {getattr(model, 'name', '?')!r} has no parameter {key!r}; "
                                  f"its parameters: {', '.join(declared) or 'none'}"))
            continue
        channels = int(getattr(p, "channels", 1))
        shape = "a number" if channels == 1 else f"a number or a list of {channels} numbers (one per channel)"
        items = value if isinstance(value, list) else [value]
        if isinstance(value, list) and len(value) not in (1, channels):
            problems.append((key, f"{where}.{key} has {len(value)} values; expected {shape}"))
            continue
        numbers_: list[float] = []
        for v in items:
            if isinstance(v, bool) or not isinstance(v, (numbers.Real, str)) or \
                    (isinstance(v, str) and not _YAML11_FLOAT.match(v)):
                problems.append((key, f"{where}.{key} should be {shape}, got {type(v).__name__} {_short(v)}"))
                break
            try:
                numbers_.append(float(v))
            except OverflowError:  # an integer literal beyond the largest float
                problems.append((key, f"{where}.{key} = {_short(v)} is too large for a float"))
                break
        if len(numbers_) != len(items):
            continue
        lo, hi = (float(b) for b in getattr(p, "bounds", (-math.inf, math.inf)))
        for v in numbers_:
            if not math.isfinite(v):
                problems.append((key, f"{where}.{key} is not a finite number: {v!r}"))
                break
            if not lo <= v <= hi:
                unit = f" {p.unit}" if getattr(p, "unit", "") else ""
                problems.append((key, f"{where}.{key} = {v:g} is outside the parameter's valid range "
                                      f"[{lo:g}, {hi:g}]{unit}"))
                break
    return problems


def plugin_reference(category: str, what: str) -> tuple[Param, Param]:
    """The sub-schema of a parameter naming another plugin and its parameters: ``{device: ..., params: {...}}``.

    ``device`` is checked against the installed plugins of ``category`` at validation.
    """
    return (
        Param("device", "str", REQUIRED, f"{what} plugin (any installed {category} plugin with its protocol)",
              extra={"plugin_category": category}),
        Param("params", "dict", {}, f"the {what}'s parameters", nullable=True),
    )


def resolve(declared: Sequence[Param], given: Mapping[str, Any] | None, owner: str) -> tuple[dict, list[tuple[str | None, str]]]:
    """Check ``given`` against ``declared``; fill defaults.

    Returns the resolved values and a list of ``(key, message)`` problems, where
    ``key`` names the offending parameter (``None`` for a missing one) so that
    callers can point at the right YAML line.
    """
    given = dict(given or {})
    by_name = {p.name: p for p in declared}
    accepted = "; ".join(p.describe() for p in declared) or "none"
    values: dict[str, Any] = {}
    problems: list[tuple[str | None, str]] = []
    for key in given:
        if key not in by_name:
            problems.append((key, f"unknown parameter {key!r} for {owner}; accepted: {accepted}"))
    for p in declared:
        if p.name in given:
            try:
                values[p.name] = p.check(given[p.name])
            except ParameterError as e:
                problems.append((p.name, f"{owner}: {e}"))
        elif p.required:
            problems.append((None, f"missing required parameter {p.name!r} for {owner}; expected {p.describe()}"))
        else:
            values[p.name] = p.default
    return values, problems


def format_table(declared: Sequence[Param]) -> str:
    """Plain-text table of parameters for ``sbrdf plugins``."""
    if not declared:
        return "    (no parameters)"
    return "\n".join(f"    {p.describe()}" + (f"\n        {p.doc}" if p.doc else "") for p in declared)
