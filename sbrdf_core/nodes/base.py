"""What a node kind is: typed ports, an output artifact kind, a ``prepare`` and a ``build``.

``build`` describes the computation as lazy dask arrays and never computes;
the runner (:mod:`sbrdf_core.runner`) decides which chunks still need writing
and executes them.  What ``build`` must know as concrete values (per-pose
marker measurements, a codebook) is declared by ``prepare`` as lazy dask
collections: the runner computes them on the run's scheduler, with the node's
progress bar, and hands the results to ``build`` in ``ctx.prepared``.  So
building never computes on whatever scheduler happens to be ambient.  Kernels
stay plain NumPy so they can be tested without dask.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

from ..artifacts import ArtifactKind
from ..params import Param

if TYPE_CHECKING:
    import dask.array as da

    from ..plugin import PluginSpec
    from ..store import Artifact
    from ..types import PluginRegistry


def shared(obj: Any):
    """``obj`` as one graph key, fetched once per worker by the tasks that take it.

    A per-pose object (a capture manifest, a Registration, every pose's light
    position) passed as a plain task argument is copied into every task; on a
    distributed cluster each copy is pickled on its own, so queued tasks hold
    O(poses²) bytes (tests/core/test_runner_memory.py).
    """
    from dask import delayed

    return delayed(obj, pure=True, traverse=False)


@dataclass(frozen=True)
class Port:
    """A typed input of a node kind: which artifact kinds it accepts."""

    name: str
    kinds: tuple[ArtifactKind | str, ...]
    doc: str = ""
    #: An optional input may be left out of ``in:``; the node then works without it.
    optional: bool = False

    def accepts(self, kind: ArtifactKind) -> bool:
        return kind.kind in self.names

    @property
    def names(self) -> tuple[str, ...]:
        """Accepted kind names; a kind declared by a plugin may be given by name in ``kinds``."""
        return tuple(k if isinstance(k, str) else k.kind for k in self.kinds)

    @property
    def kind_names(self) -> str:
        return " or ".join(self.names)


@dataclass
class Output:
    """A node's lazy result: the arrays to write and how to finish the artifact.

    Parameters
    ----------
    arrays
        Output name -> lazy dask array.  Stored chunks equal the dask chunks
        unless ``chunks`` says otherwise (the runner rechunks lazily).
    chunks
        Optional zarr chunk shape per array: what one task writes.
    inner_chunks
        Optional smaller chunk shape per array that readers fetch: each written
        chunk is then a zarr shard of these (Register writes a pose block whole;
        Reflectance reads one texel tile of it).
    attrs
        JSON attributes known at build time (e.g. model name, texel grid).
    finalize
        Called after every chunk is written with the (still incomplete)
        artifact; returns more attributes (summary statistics, files written
        beside the arrays).  The artifact is marked complete after it.
    sequential
        Compute chunks one at a time, in order, in this process (hardware).
    stream
        Chunks at different positions on the first ``stream`` chunk axes share
        no work but data keys (``shared``): the runner then computes each such
        group of chunks as one task and, on a cluster, keeps a bounded window
        of groups in flight (:mod:`sbrdf_core.streaming`), so memory does not
        grow with the number of chunks.  Register streams pose blocks (1),
        Reflectance texel tiles (2).  Leave it 0 when chunks share a computation
        (a global reduction, a codebook), which each group would repeat.
    """

    arrays: dict[str, da.Array]
    chunks: dict[str, tuple[int, ...]] = field(default_factory=dict)
    inner_chunks: dict[str, tuple[int, ...]] = field(default_factory=dict)
    attrs: dict[str, Any] = field(default_factory=dict)
    finalize: Callable[[Artifact], Mapping[str, Any]] | None = None
    sequential: bool = False
    stream: int = 0


@dataclass
class BuildContext:
    """Everything a node kind's ``build`` may use."""

    node: str
    params: dict[str, Any]
    inputs: dict[str, Artifact]
    plugin: Any = None
    spec: PluginSpec | None = None
    registry: PluginRegistry | None = None
    url: str = ""
    #: What :meth:`NodeKind.prepare` asked for, computed (same keys, NumPy/Python values);
    #: ``None`` until the runner has run the prepare step.
    prepared: dict[str, Any] | None = None

    @property
    def plugin_name(self) -> str:
        """The registry name of the node's plugin (a node kind with ``plugin_category`` always has one)."""
        if self.spec is None:
            raise RuntimeError(f"node {self.node!r} has no plugin")
        return self.spec.name

    def plugins(self) -> PluginRegistry:
        """The run's registry (every node the runner builds has one)."""
        if self.registry is None:
            raise RuntimeError(f"node {self.node!r} was built without a registry")
        return self.registry

    def key(self, prefix: str) -> str:
        """A dask key name for this node's ``prefix`` tasks: ``<prefix>-<node>-<8 hex digits>``.

        The digits hash the artifact's URL, its inputs' tokens and the node's
        parameters, so two runs sharing a distributed scheduler (a batch of
        scans, whose nodes have the same names) never share a key, and so never
        each other's results.  dask's ``key_split`` drops the digits: dashboards
        and task counts still see ``<prefix>-<node>``.
        """
        import hashlib

        ident = repr((self.url, sorted((p, getattr(a, "token", None)) for p, a in self.inputs.items()), sorted(self.params.items())))
        return f"{prefix}-{self.node}-{hashlib.sha1(ident.encode()).hexdigest()[:8]}"


class NodeKind:
    """Base class of node kinds; subclasses set the class attributes and ``build``."""

    name: ClassVar[str]
    doc: ClassVar[str] = ""
    inputs: ClassVar[tuple[Port, ...]] = ()
    output: ClassVar[ArtifactKind]
    #: Category of the plugin a node of this kind names, or ``None`` if it takes none.
    plugin_category: ClassVar[str | None] = None
    #: Plugin used when the YAML omits ``plugin:``.
    default_plugin: ClassVar[str | None] = None
    #: Parameters of the node itself, accepted beside the plugin's.
    params: ClassVar[tuple[Param, ...]] = ()

    @classmethod
    def port(cls, name: str) -> Port | None:
        return next((p for p in cls.inputs if p.name == name), None)

    @classmethod
    def fingerprint(cls, ctx: BuildContext) -> str:
        """Extra cache-key material beyond parameters and inputs (e.g. files on disk)."""
        from ..contracts import optional

        fp = optional(ctx.plugin, "fingerprint")
        return fp() if callable(fp) else ""

    @classmethod
    def prepare(cls, ctx: BuildContext) -> dict[str, Any]:
        """Lazy dask collections ``build`` needs computed, by name; the runner computes them first.

        The default asks for nothing.  A node kind whose plugin needs concrete
        data delegates to the plugin's optional ``prepare`` with the inputs of
        its main call (Register: ``plugin.prepare(capture)``).
        """
        return {}

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:  # pragma: no cover - abstract
        raise NotImplementedError
