"""A model's fit kernel in GLSL: the ``brdf_fit_gradient`` the GPU fitter ``lm-gl`` runs.

A model writes its mathematics once, as ``fit_kernel(x, cfg, wi, wo, f, J)``
(:mod:`sbrdf_core.engine`, which compiles it with numba for the CPU).
:func:`fit_gradient_glsl` reads the same function's source (``inspect`` and
:mod:`ast`) and writes its statements in GLSL 4.3::

    vec3 brdf_fit_gradient(vec3 wi, vec3 wo, float x[K], out vec3 J[K]);

which returns f and sets ``J[k][c]`` = ∂f_c/∂x_k (the kernel's ``J[c, k]``),
K = ``fit_form().size``, three channels.  The fit form's ``kernel_config()``
is baked in: ``cfg[i]`` becomes its number, and whatever follows from
numbers alone is folded (module constants, ``x.size``, ``int(cfg[0])``, a
local assigned once from them), so an ``if`` on the configuration keeps only
its branch, as a hand-written shader would.  Both paths run the one function,
so they cannot drift; ``BRDFModelTests.test_glsl_fit_gradient_matches_numpy``
checks the GLSL against the fit form's NumPy ``eval`` and ``jacobian``.

The Python it reads is what the kernels use: ``for`` over ``range(...)`` or
over a tuple, ``if``/``elif``/``else``, ``return``, ``break``/``continue``,
assignment (chained, tuple unpacking), ``+= -= *= /=``, arithmetic, ``**``,
comparisons (chained), ``and``/``or``/``not``, ``a if c else b``;
``math.exp log sqrt sin cos tan atan2 pow fabs erfc`` and ``math.pi``/``math.e``,
``abs min max int float``; ``x.size``, ``f.size``, ``J.shape``; subscripts
``x[i]``, ``cfg[i]``, ``wi[i]``, ``f[c]``, ``J[c, k]``; numbers named at
module level.  Each local is int, float, bool or vec3 (a name for ``wi`` or
``wo``), from what is assigned to it (int and float: float); loop counters
and ``int(...)`` are int, ``/`` is always float division.  Anything else
raises :class:`KernelSubsetError` naming the model, the construct and the
kernel's line.

Float32 differs from the kernel's float64 in three places, each documented
where it is made: a literal below float's smallest normal number is written
as that number (a floor of 1e-300 stays a positive floor), ``x ** n`` with
an integer n is a product (``pow`` is undefined for x < 0), and
``math.erfc`` is Abramowitz & Stegun 7.1.26 (|error| < 1.5e-7).
"""

from __future__ import annotations

import ast
import builtins
import functools
import inspect
import math
import operator
import textwrap
from typing import Any, NamedTuple, NoReturn

import numpy as np

from .errors import SbrdfError

__all__ = ["KernelSubsetError", "fit_gradient_glsl", "kernel_glsl"]

FLT_MIN, FLT_MAX = float(np.finfo(np.float32).tiny), float(np.finfo(np.float32).max)

#: Helper functions a translation may call, emitted ahead of ``brdf_fit_gradient`` where used.
HELPERS = {
    "sbrdf_powi": "float sbrdf_powi(float b, int n) {  // b ** n for a constant n >= 0, negative b included\n"
                  "    float r = 1.0;\n    for (int i = 0; i < n; ++i) r *= b;\n    return r;\n}\n",
    "sbrdf_erfc": "float sbrdf_erfc(float a) {  // Abramowitz & Stegun 7.1.26, |error| < 1.5e-7\n"
                  "    float z = abs(a), t = 1.0 / (1.0 + 0.3275911 * z);\n"
                  "    float r = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027\n"
                  "        + t * 1.061405429)))) * exp(-z * z);\n"
                  "    return a < 0.0 ? 2.0 - r : r;\n}\n",
}
_CALLS = {math.exp: "exp", math.log: "log", math.sqrt: "sqrt", math.sin: "sin", math.cos: "cos", math.tan: "tan",
          math.atan2: "atan",  # atan2(y, x) is GLSL's atan(y, x)
          math.pow: "pow", math.fabs: "abs", math.erfc: "sbrdf_erfc",
          abs: "abs", min: "min", max: "max", int: "int", float: "float"}
_ARITY = {"atan": 2, "pow": 2, "min": None, "max": None}  # None: two or more; the rest take one
# Operator, GLSL symbol and precedence (higher binds tighter); operands of lower precedence are parenthesised.
_BINOPS = {ast.Add: ("+", 7, operator.add), ast.Sub: ("-", 7, operator.sub), ast.Mult: ("*", 8, operator.mul),
           ast.Div: ("/", 8, operator.truediv)}
_COMPARE = {ast.Eq: ("==", 5, operator.eq), ast.NotEq: ("!=", 5, operator.ne), ast.Lt: ("<", 6, operator.lt),
            ast.LtE: ("<=", 6, operator.le), ast.Gt: (">", 6, operator.gt), ast.GtE: (">=", 6, operator.ge)}
TERNARY, OR, AND, UNARY, PRIMARY = 1, 2, 3, 9, 10
#: Names a local may not keep in GLSL (keywords, reserved words, the built-ins a translation calls): prefixed py_.
RESERVED = frozenset("""attribute const uniform varying buffer shared coherent volatile restrict readonly writeonly
    layout centroid flat smooth noperspective patch sample break continue do for while switch case default if else
    subroutine in out inout float double int uint void bool true false invariant precise discard return struct
    vec2 vec3 vec4 ivec2 ivec3 ivec4 bvec2 bvec3 bvec4 uvec2 uvec3 uvec4 dvec2 dvec3 dvec4 mat2 mat3 mat4 lowp mediump
    highp precision common partition active asm class union enum typedef template this resource goto inline noinline
    public static extern external interface long short half fixed unsigned superp input output filter sizeof cast
    namespace using exp log sqrt sin cos tan atan pow abs min max dot cross length normalize clamp mix step sign floor
    ceil fract mod inversesqrt exp2 log2 isnan isinf""".split())


class KernelSubsetError(SbrdfError):
    """A fit kernel uses Python outside what :mod:`sbrdf_core.engine_glsl` translates; the message says what and where."""


class _Pending(Exception):
    """Type inference met a local whose type is not known yet (assigned further on): try again next pass."""


class E(NamedTuple):
    """A translated expression: GLSL text, type, precedence, and its Python value where it is a constant."""

    code: str
    type: str  # int float bool vec3, or x cfg f J shape module: the parameters and what only indexing reads
    prec: int = PRIMARY
    value: Any = None


def fit_gradient_glsl(model) -> str | None:
    """``brdf_fit_gradient`` translated from ``model``'s fit-form ``fit_kernel``, or None where it has none."""
    form = model.fit_form()
    kernel = getattr(form, "kernel", None)
    if kernel is None:
        return None
    cfg = tuple(float(v) for v in np.asarray(form.kernel_config(), np.float64).ravel())
    name = getattr(model, "name", type(model).__name__)
    return kernel_glsl(getattr(kernel, "py_func", kernel), cfg, form.size, getattr(form, "channels", 3), name)


@functools.lru_cache(maxsize=128)
def kernel_glsl(kernel, cfg: tuple[float, ...], K: int, channels: int = 3, model: str = "model") -> str:
    """``brdf_fit_gradient`` translated from the plain-Python ``kernel`` with ``cfg`` baked in, ``K`` parameters."""
    if channels != 3:
        raise KernelSubsetError(f"{model}: the GLSL fit gradient has 3 channels, the fit form {channels}")
    return _Translator(kernel, cfg, K, model).run()


def glsl_name(name: str) -> str:
    """A Python name as a GLSL identifier: reserved words and names GLSL reserves (``_x``, ``a__b``, ``gl_``) get py_."""
    bad = name in RESERVED or name.startswith(("_", "gl_", "sbrdf_")) or "__" in name
    return "py" + ("" if name.startswith("_") else "_") + name if bad else name


class _Translator:
    def __init__(self, kernel, cfg, K, model):
        lines, self.first = inspect.getsourcelines(kernel)
        fn = ast.parse(textwrap.dedent("".join(lines))).body[0]
        self.where = f"{model}: fit kernel {kernel.__module__}.{kernel.__qualname__}"
        if not isinstance(fn, ast.FunctionDef):
            raise KernelSubsetError(f"{self.where}: not a plain function")
        self.fn, self.globals, self.cfg, self.K = fn, kernel.__globals__, cfg, K
        a = fn.args
        if len(a.args) != 6 or a.vararg or a.kwarg or a.kwonlyargs or a.posonlyargs or a.defaults:
            self.fail(fn, "a signature other than fit_kernel(x, cfg, wi, wo, f, J)")
        names = [p.arg for p in a.args]
        self.names = names
        self.params = dict(zip(names, ("x", "cfg", "vec3", "vec3", "f", "J")))
        self.sizes = {"x": K, "f": 3, "vec3": 3}
        stores = [n.id for n in ast.walk(fn) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)]
        self.stored = set(stores)
        self.once = {n for n in self.stored if stores.count(n) == 1}
        ranges = [n.target.id for n in ast.walk(fn) if isinstance(n, ast.For) and self.is_range(n.iter)
                  and isinstance(n.target, ast.Name)]
        #: Names only ever range counters: declared in their for, not at the top.
        self.counters = {n for n in ranges if stores.count(n) == ranges.count(n)}
        self.types: dict[str, str] = {}  # locals GLSL declares
        self.consts: dict[str, object] = {}  # locals assigned one number, written as it
        self.loops: list[str] = []  # the range counters in scope
        self.helpers: set[str] = set()
        self.out: list[str] = []
        self.prev: tuple[dict, dict] = ({}, {})  # the last inference pass's types and constants
        self.depth, self.serial, self.inferring = 1, 0, False

    def fail(self, node, what: str) -> NoReturn:
        line = self.first + getattr(node, "lineno", 1) - 1
        raise KernelSubsetError(f"{self.where}, line {line}: {what} is not in the Python a fit kernel may use in "
                                "GLSL (sbrdf_core.engine_glsl)")

    # -- types, found before any GLSL is written --------------------------------------------------

    def run(self) -> str:
        self.inferring = True
        seen = None
        for _ in range(4):  # a pass per loop-carried dependence; kernels settle in two
            self.prev, self.types, self.consts = (dict(self.types), dict(self.consts)), {}, {}
            self.infer(self.fn.body)
            if seen == (self.types, self.consts):
                break
            seen = (dict(self.types), dict(self.consts))
        self.inferring, self.helpers = False, set()
        self.block(self.fn.body)
        decl = [f"    {t} {line.replace(' ', ', ')};" for t in ("int", "float", "bool", "vec3")
                for line in textwrap.wrap(" ".join(glsl_name(n) for n in sorted(self.types) if self.types[n] == t), 90)]
        K = self.K
        x, wi, wo, f, J = (glsl_name(self.names[i]) for i in (0, 2, 3, 4, 5))
        cfg = ", ".join(repr(v) for v in self.cfg)
        head = [f"// {self.where.split(': ', 1)[1]}, cfg = ({cfg}), in GLSL by sbrdf_core.engine_glsl"]
        head += [HELPERS[h] for h in sorted(self.helpers)]
        head += [f"vec3 brdf_fit_gradient(vec3 {wi}, vec3 {wo}, float {x}[{K}], out vec3 {J}[{K}]) {{",
                 f"    vec3 {f} = vec3(0.0);", f"    for (int py_k = 0; py_k < {K}; ++py_k) {J}[py_k] = vec3(0.0);"]
        return "\n".join(head + decl + self.out + [f"    return {f};", "}", ""])

    def unify(self, name: str, t: str, node) -> None:
        if t not in ("int", "float", "bool", "vec3"):
            self.fail(node, f"the local {name!r} naming the parameter {t}")
        old = self.types.get(name, t)
        if old != t and {old, t} != {"int", "float"}:
            self.fail(node, f"{name!r} holding both {old} and {t}")
        self.types[name] = "float" if old != t else t

    def infer(self, stmts) -> None:
        for s in stmts:
            if isinstance(s, ast.Assign):
                self._infer_assign(s)
            elif isinstance(s, ast.AugAssign) and isinstance(s.target, ast.Name):
                try:
                    self.unify(s.target.id, self.binop(s.op, self.ex(s.target), self.ex(s.value), s).type, s)
                except _Pending:
                    pass
            elif isinstance(s, ast.If):
                try:
                    known = self.truth(self.ex(s.test), s).value
                except _Pending:
                    known = None
                if known is not None:
                    self.infer(s.body if known else s.orelse)
                else:
                    self.infer(s.body)
                    self.infer(s.orelse)
            elif isinstance(s, ast.For):
                self._infer_for(s)

    def _infer_assign(self, s: ast.Assign) -> None:
        for target, value in self.pairs(s):
            if isinstance(target, ast.Name):
                try:
                    e = self.ex(value)
                except _Pending:
                    continue
                if target.id in self.once and e.value is not None:
                    self.consts[target.id] = e.value
                else:
                    self.unify(target.id, e.type, s)

    def _infer_for(self, s: ast.For) -> None:
        name = s.target.id if isinstance(s.target, ast.Name) else ""
        if self.is_range(s.iter) or not name:
            if name and name not in self.counters:  # also assigned outside its loops: declared
                self.unify(name, "int", s)
            self.loops.append(name)
            self.infer(s.body)
            self.loops.pop()
            return
        try:
            for e in self.items(s):
                self.unify(name, e.type, s)
        except _Pending:
            pass
        self.infer(s.body)

    # -- expressions --------------------------------------------------------------------------------

    def lit(self, v, node) -> E:
        if isinstance(v, (bool, np.bool_)):
            return E("true" if v else "false", "bool", PRIMARY, bool(v))
        if isinstance(v, (int, np.integer)):
            if not -2**31 <= v < 2**31:
                self.fail(node, f"the integer {v} (GLSL int is 32-bit)")
            return E(str(int(v)), "int", PRIMARY if v >= 0 else UNARY, int(v))
        v = float(v)
        if not math.isfinite(v) or abs(v) > FLT_MAX:
            self.fail(node, f"the number {v!r} (beyond float32)")
        text = repr(math.copysign(FLT_MIN, v) if 0 < abs(v) < FLT_MIN else v)  # a floor stays positive in float32
        return E(text, "float", PRIMARY if v >= 0 else UNARY, v)

    def ex(self, n) -> E:
        if isinstance(n, E):
            return n
        method = getattr(self, "_" + type(n).__name__, None)
        if method is None:
            self.fail(n, f"the expression {ast.unparse(n)!r}")
        return method(n)

    def _Constant(self, n):
        if isinstance(n.value, (bool, int, float)):
            return self.lit(n.value, n)
        self.fail(n, f"the constant {n.value!r}")

    def _Name(self, n):
        v = n.id
        if v in self.stored:
            for known in (self.consts, self.prev[1]) if self.inferring else (self.consts,):
                if v in known:
                    return self.lit(known[v], n)
            for types in (self.types, self.prev[0]) if self.inferring else (self.types,):
                if v in types:
                    return E(glsl_name(v), types[v])
            if v in self.loops:
                return E(glsl_name(v), "int")
            if self.inferring:
                raise _Pending(v)
            self.fail(n, f"reading {v!r} where it is not assigned (before, or after its loop)")
        if v in self.params:
            return E(glsl_name(v), self.params[v])
        g = self.globals.get(v, getattr(builtins, v, None))
        if isinstance(g, (bool, int, float, np.number, np.bool_)):
            return self.lit(g.item() if isinstance(g, np.generic) else g, n)
        if g is math:
            return E("math", "module")
        self.fail(n, f"the name {v!r} (a module constant must be a number)")

    def _Attribute(self, n):
        base = self.ex(n.value)
        if base.type == "module" and isinstance(getattr(math, n.attr, None), float):
            return self.lit(getattr(math, n.attr), n)
        if n.attr == "size" and base.type in self.sizes:
            return self.lit(self.sizes[base.type], n)
        if n.attr == "shape" and base.type == "J":
            return E("", "shape", value=(3, self.K))
        self.fail(n, f"the attribute {ast.unparse(n)!r}")

    def index(self, n, size: int | None) -> E:
        i = self.ex(n)
        if i.type != "int":
            self.fail(n, f"the {i.type} index {ast.unparse(n)!r}")
        if i.value is not None and size is not None:
            if not -size <= i.value < size:
                self.fail(n, f"the index {ast.unparse(n)} = {i.value} out of 0..{size - 1}")
            return self.lit(i.value % size, n)
        return i

    def _Subscript(self, n):
        base = self.ex(n.value)
        if base.type == "J":
            if not (isinstance(n.slice, ast.Tuple) and len(n.slice.elts) == 2):
                self.fail(n, f"{ast.unparse(n)!r} (J takes J[c, k])")
            c, k = self.index(n.slice.elts[0], 3), self.index(n.slice.elts[1], self.K)
            return E(f"{base.code}[{k.code}][{c.code}]", "float")
        if base.type == "shape":
            i = self.index(n.slice, 2)
            if i.value is None:
                self.fail(n, f"J.shape indexed by the variable {ast.unparse(n.slice)!r}")
            return self.lit(base.value[i.value], n)
        if base.type == "cfg":
            i = self.index(n.slice, len(self.cfg))
            if i.value is None:
                self.fail(n, f"cfg indexed by the variable {ast.unparse(n.slice)!r}")
            return self.lit(self.cfg[i.value], n)
        if base.type in self.sizes:
            return E(f"{base.code}[{self.index(n.slice, self.sizes[base.type]).code}]", "float")
        self.fail(n, f"the subscript {ast.unparse(n)!r}")

    def number(self, e: E, node) -> E:
        if e.type not in ("int", "float"):
            self.fail(node, f"arithmetic on a {e.type} ({ast.unparse(node)!r})")
        return e

    def flt(self, e: E, node) -> E:
        """``e`` as a float (an int is converted: GLSL mixes no types)."""
        if self.number(e, node).type == "float":
            return e
        return self.lit(float(e.value), node) if e.value is not None else E(f"float({e.code})", "float")

    def truth(self, e: E, node) -> E:
        """``e`` as a condition: a number is true where it is not 0, as in Python."""
        if e.type == "bool":
            return e
        zero = "0" if self.number(e, node).type == "int" else "0.0"
        return E(f"{wrap(e, 6)} != {zero}", "bool", 5, None if e.value is None else bool(e.value))

    def binop(self, op, a: E, b: E, node) -> E:
        a, b = self.number(a, node), self.number(b, node)
        if isinstance(op, ast.Pow):
            return self.power(a, b, node)
        if type(op) not in _BINOPS:
            self.fail(node, f"the operator {type(op).__name__}")
        sym, prec, fold = _BINOPS[type(op)]
        if a.value is not None and b.value is not None:
            try:
                return self.lit(fold(a.value, b.value), node)
            except ArithmeticError:
                pass
        if isinstance(op, ast.Div) or "float" in (a.type, b.type):  # Python's / is float division
            a, b = self.flt(a, node), self.flt(b, node)
        return E(f"{wrap(a, prec)} {sym} {wrap(b, prec + 1)}", a.type, prec)

    def power(self, a: E, b: E, node) -> E:
        if a.value is not None and b.value is not None:
            try:
                v = a.value ** b.value
                if not isinstance(v, complex):
                    return self.lit(v, node)
            except ArithmeticError:
                pass
        if a.type == "int":
            self.fail(node, "an int raised to a power (write float(...) ** n)")
        if b.value is not None and float(b.value).is_integer() and 0 <= b.value <= 16:
            self.helpers.add("sbrdf_powi")  # a product: pow(x, y) is undefined for x < 0
            return E(f"sbrdf_powi({a.code}, {int(b.value)})", "float")
        return E(f"pow({a.code}, {self.flt(b, node).code})", "float")

    def _BinOp(self, n):
        return self.binop(n.op, self.ex(n.left), self.ex(n.right), n)

    def _UnaryOp(self, n):
        a = self.ex(n.operand)
        if isinstance(n.op, ast.Not):
            a = self.truth(a, n)
            return E(f"!{wrap(a, PRIMARY)}", "bool", UNARY, None if a.value is None else not a.value)
        if isinstance(n.op, (ast.USub, ast.UAdd)):
            a = self.number(a, n)
            if isinstance(n.op, ast.UAdd):
                return a
            return self.lit(-a.value, n) if a.value is not None else E(f"-{wrap(a, PRIMARY)}", a.type, UNARY)
        self.fail(n, "the operator ~")

    def _Compare(self, n):
        parts, left = [], self.ex(n.left)
        for op, node in zip(n.ops, n.comparators):
            right = self.ex(node)
            if type(op) not in _COMPARE:
                self.fail(n, f"the comparison {type(op).__name__}")
            sym, prec, fold = _COMPARE[type(op)]
            a, b = left, right
            if "bool" in (a.type, b.type):
                if a.type != b.type or prec != 5:
                    self.fail(n, f"comparing a {a.type} with a {b.type}")
            elif "float" in (self.number(a, n).type, self.number(b, n).type):
                a, b = self.flt(a, n), self.flt(b, n)
            value = fold(a.value, b.value) if a.value is not None and b.value is not None else None
            parts.append(E(f"{wrap(a, prec + 1)} {sym} {wrap(b, prec + 1)}", "bool", prec, value))
            left = right
        return self.logic(parts, "&&", n)

    def logic(self, parts: list[E], sym: str, node) -> E:
        """``parts`` (bools) joined by ``&&`` or ``||``, with the known ones folded."""
        stop = sym == "||"  # the value that decides: true for ||, false for &&
        if any(p.value is stop for p in parts):
            return self.lit(stop, node)
        parts = [p for p in parts if p.value is None]
        if not parts:
            return self.lit(not stop, node)
        prec = OR if stop else AND
        if len(parts) == 1:
            return parts[0]
        return E(f" {sym} ".join(wrap(p, prec + 1) for p in parts), "bool", prec)

    def _BoolOp(self, n):
        parts = [self.ex(v) for v in n.values]
        for p, v in zip(parts, n.values):
            if p.type != "bool":
                self.fail(v, f"and/or on a {p.type} ({ast.unparse(v)!r}: Python returns the operand)")
        return self.logic(parts, "&&" if isinstance(n.op, ast.And) else "||", n)

    def _IfExp(self, n):
        test = self.truth(self.ex(n.test), n)
        if test.value is not None:  # only the branch the configuration takes: the other may index past K
            return self.ex(n.body if test.value else n.orelse)
        a, b = self.common([self.ex(n.body), self.ex(n.orelse)], n)
        return E(f"{wrap(test, OR)} ? {wrap(a, OR)} : {wrap(b, OR)}", a.type, TERNARY)

    def common(self, es: list[E], node) -> list[E]:
        """``es`` in one type (ints with floats: all floats), or an error."""
        types = {e.type for e in es}
        if types == {"int", "float"}:
            return [self.flt(e, node) for e in es]
        if len(types) != 1 or types & {"x", "cfg", "f", "J", "shape", "module"}:
            self.fail(node, f"{ast.unparse(node)!r} mixing {', '.join(sorted(types))}")
        return es

    def call_args(self, n: ast.Call, name: str) -> list[E]:
        """The arguments of a call of the GLSL function ``name``: as many as it takes, of the types it takes."""
        args = [self.ex(a) for a in n.args]
        arity = _ARITY.get(name, 1)
        if (len(args) < 2) if arity is None else len(args) != arity:
            self.fail(n, f"{ast.unparse(n.func)} with {len(args)} arguments")
        for a, node in zip(args, n.args):
            if a.type not in (("int", "float", "bool") if name in ("int", "float") else ("int", "float")):
                self.fail(node, f"{ast.unparse(n.func)} of a {a.type}")
        return args

    def _Call(self, n):
        fn = self.callee(n.func)
        name = next((glsl for py, glsl in _CALLS.items() if py is fn), None)
        if name is None or n.keywords:
            self.fail(n, f"the call {ast.unparse(n)!r}")
        args = self.call_args(n, name)
        if all(a.value is not None for a in args):
            try:
                return self.lit(fn(*(a.value for a in args)), n)
            except (ArithmeticError, ValueError):
                pass
        if name in ("int", "float"):
            return E(f"{name}({args[0].code})", name)
        if name == "pow":
            return self.power(self.flt(args[0], n), args[1], n)
        if name in ("min", "max", "abs") and {a.type for a in args} == {"int"}:
            t = "int"
        else:
            t, args = "float", [self.flt(a, node) for a, node in zip(args, n.args)]
        if name == "sbrdf_erfc":
            self.helpers.add(name)
        code = args[-1].code
        for a in reversed(args[:-1]):  # min(a, b, c) is min(a, min(b, c))
            code = f"{name}({a.code}, {code})"
        return E(code if len(args) > 1 else f"{name}({code})", t)

    def callee(self, node):
        """The Python object a call names, where it is a module-level name or an attribute of one."""
        if isinstance(node, ast.Name) and node.id not in self.stored and node.id not in self.params:
            return self.globals.get(node.id, getattr(builtins, node.id, None))
        if isinstance(node, ast.Attribute):
            base = self.callee(node.value)
            return getattr(base, node.attr, None) if inspect.ismodule(base) else None
        return None

    def is_range(self, node) -> bool:
        return isinstance(node, ast.Call) and self.callee(node.func) is range

    # -- statements ---------------------------------------------------------------------------------

    def emit(self, line: str) -> None:
        self.out.append("    " * self.depth + line)

    def block(self, stmts, indent: bool = False) -> None:
        self.depth += indent
        for s in stmts:
            method = getattr(self, "_s_" + type(s).__name__, None)
            if method is None:
                self.fail(s, f"the statement {type(s).__name__} ({ast.unparse(s).splitlines()[0]!r})")
            method(s)
        self.depth -= indent

    def pairs(self, s: ast.Assign) -> list:
        """The (target, value) pairs of an assignment: chained targets and tuples unpacked."""
        out = []
        for target in s.targets:
            if isinstance(target, (ast.Tuple, ast.List)):
                values: list = []
                if isinstance(s.value, (ast.Tuple, ast.List)):
                    values = list(s.value.elts)
                else:
                    shape = self.ex(s.value)
                    if shape.type != "shape":
                        self.fail(s, "unpacking anything but a tuple or J.shape")
                    values = [self.lit(v, s) for v in shape.value]
                if len(values) != len(target.elts) or any(isinstance(t, ast.Starred) for t in target.elts):
                    self.fail(s, "unpacking into a different number of names")
                out += list(zip(target.elts, values))
            else:
                out.append((target, s.value))
        return out

    def target(self, t, node) -> E:
        """What an assignment writes: a local, ``f[c]`` or ``J[c, k]``."""
        if isinstance(t, ast.Name):
            if t.id in self.params:
                self.fail(node, f"assigning to the parameter {t.id!r}")
            if t.id not in self.types:
                self.fail(node, f"assigning {t.id!r}, whose type follows from nothing assigned before")
            return E(glsl_name(t.id), self.types[t.id])
        if isinstance(t, ast.Subscript) and self.ex(t.value).type in ("f", "J"):
            return self.ex(t)
        self.fail(node, f"assigning to {ast.unparse(t)!r} (a kernel writes f[c], J[c, k] and its locals)")

    def to(self, t: str, e: E, node) -> E:
        """``e`` as a value of type ``t`` (an int made a float; nothing else converts)."""
        if t == "float":
            return self.flt(e, node)
        if t != e.type:
            self.fail(node, f"assigning a {e.type} to a {t}")
        return e

    def store(self, t: E, e: E, node) -> str:
        return f"{t.code} = {self.to(t.type, e, node).code};"

    def _s_Assign(self, s):
        pairs = [(t, v) for t, v in self.pairs(s) if not (isinstance(t, ast.Name) and t.id in self.consts)]
        written: set[str] = set()
        clash = False
        for t, v in pairs:  # Python evaluates every value first: a value reading an earlier target needs a copy
            reads = {n.id for n in ast.walk(v) if isinstance(n, ast.Name)} if isinstance(v, ast.AST) else set()
            clash |= bool(reads & written)
            written |= {n.id for n in ast.walk(t) if isinstance(n, ast.Name)}
        if not clash:
            for t, v in pairs:
                self.emit(self.store(self.target(t, s), self.ex(v), s))
            return
        self.emit("{")
        copies = []
        for j, (_, v) in enumerate(pairs):
            e = self.ex(v)
            self.emit(f"    {e.type} py_copy{j} = {e.code};")
            copies.append(E(f"py_copy{j}", e.type))
        for (t, _), e in zip(pairs, copies):
            self.emit("    " + self.store(self.target(t, s), e, s))
        self.emit("}")

    def _s_AugAssign(self, s):
        t, v = self.target(s.target, s), self.ex(s.value)
        r = self.binop(s.op, t, v, s)
        if type(s.op) not in _BINOPS or r.type != t.type:
            return self.emit(self.store(t, r, s))
        self.emit(f"{t.code} {_BINOPS[type(s.op)][0]}= {self.to(t.type, v, s).code};")

    def _s_If(self, s, head: str = "if"):
        test = self.truth(self.ex(s.test), s)
        if test.value is not None:  # the configuration decides: only its branch (the other may index past K)
            return self.block(s.body if test.value else s.orelse)
        self.emit(f"{head} ({test.code}) {{")
        self.block(s.body, indent=True)
        rest = s.orelse
        if len(rest) == 1 and isinstance(rest[0], ast.If) and self.truth(self.ex(rest[0].test), s).value is None:
            return self._s_If(rest[0], "} else if")
        if rest:
            self.emit("} else {")
            self.block(rest, indent=True)
        self.emit("}")

    def items(self, s: ast.For) -> list[E]:
        if not isinstance(s.iter, (ast.Tuple, ast.List)):
            self.fail(s, f"a for over {ast.unparse(s.iter)!r} (range(...) or a tuple)")
        return self.common([self.ex(e) for e in s.iter.elts], s)

    def _s_For(self, s):
        if s.orelse or not isinstance(s.target, ast.Name):
            self.fail(s, "for with else, or with more than one name")
        if self.is_range(s.iter):
            self._for_range(s, s.target.id)
        else:
            self._for_items(s, s.target.id)

    def _for_items(self, s: ast.For, v: str) -> None:
        """``for v in (a, b, ...)``: a GLSL array of the items and an index over it."""
        es = self.items(s)
        self.serial += 1
        seq, i = f"py_items{self.serial}", f"py_i{self.serial}"
        t, n = self.types[v], len(es)
        self.emit(f"{t} {seq}[{n}] = {t}[{n}](" + ", ".join(self.to(t, e, s).code for e in es) + ");")
        self.emit(f"for (int {i} = 0; {i} < {n}; ++{i}) {{")
        self.emit(f"    {glsl_name(v)} = {seq}[{i}];")
        self.block(s.body, indent=True)
        self.emit("}")

    def _for_range(self, s: ast.For, v: str) -> None:
        """``for v in range(...)``: a counted GLSL loop, its bounds and counter not changed in the body."""
        name = glsl_name(v)
        body_stores = {n.id for b in s.body for n in ast.walk(b) if isinstance(n, ast.Name)
                       and isinstance(n.ctx, ast.Store)}
        start, stop, step = self._range(s)
        if v in body_stores:
            self.fail(s, f"assigning to the loop counter {v!r} in its loop")
        if {n.id for n in ast.walk(s.iter) if isinstance(n, ast.Name)} & body_stores:
            self.fail(s, "a range whose bounds change in the loop")
        declared = v in self.types
        if declared and self.types[v] != "int":
            self.fail(s, f"{v!r} counting a range and holding a {self.types[v]}")
        step_code = {1: f"++{name}", -1: f"--{name}"}.get(step.value, f"{name} += {step.code}")
        self.emit(f"for ({'' if declared else 'int '}{name} = {start.code}; {name} {'<' if step.value > 0 else '>'} "
                  f"{stop.code}; {step_code}) {{")
        self.loops.append(v)
        self.block(s.body, indent=True)
        self.loops.pop()
        self.emit("}")

    def _range(self, s: ast.For) -> tuple[E, E, E]:
        """``(start, stop, step)`` of ``for _ in range(...)``: one to three ints, the step a nonzero constant."""
        call = s.iter
        assert isinstance(call, ast.Call)  # is_range
        args = [self.ex(a) for a in call.args]
        if not 1 <= len(args) <= 3 or call.keywords or any(a.type != "int" for a in args):
            self.fail(s, f"{ast.unparse(call)!r} (range of one to three ints)")
        start, stop, step = (self.lit(0, s), args[0], self.lit(1, s)) if len(args) == 1 else (*args[:2], (
            args[2] if len(args) == 3 else self.lit(1, s)))
        if not step.value:
            self.fail(s, "a range whose step is not a nonzero constant")
        return start, stop, step

    def _s_Return(self, s):
        if s.value is not None and not (isinstance(s.value, ast.Constant) and s.value.value is None):
            self.fail(s, "returning a value (a kernel writes f and J)")
        self.emit(f"return {glsl_name(self.names[4])};")

    def _s_Expr(self, s):
        if not (isinstance(s.value, ast.Constant) and isinstance(s.value.value, str)):  # a docstring
            self.fail(s, f"the statement {ast.unparse(s)!r}")

    def _s_Pass(self, s):
        pass

    def _s_Break(self, s):
        self.emit("break;")

    def _s_Continue(self, s):
        self.emit("continue;")


def wrap(e: E, prec: int) -> str:
    """``e``'s text, in parentheses where it binds less tightly than ``prec``."""
    return e.code if e.prec >= prec else f"({e.code})"
