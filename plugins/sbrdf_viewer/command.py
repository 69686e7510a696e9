"""The viewer's commands: ``sbrdf view RUN/NODE`` writes the viewer page of a fitted or quantized SBRDF and
serves it on localhost; ``sbrdf plot RUN/NODE`` draws McAllister's three SBRDF views as PNG files.

The module imports nothing heavy: every ``sbrdf`` invocation loads it to declare the subcommands' arguments."""

from __future__ import annotations

from pathlib import Path

from sbrdf_core.params import Param


class _Command:
    """What a subcommand plugin holds: no parameters of its own, and the registry it is bound to."""

    params: tuple[Param, ...] = ()

    def __init__(self):
        self.registry = None

    def bind(self, registry) -> None:
        self.registry = registry


class ViewCommand(_Command):
    """The ``view`` subcommand (category ``command``)."""

    @staticmethod
    def add_arguments(parser) -> None:
        parser.add_argument("artifact", metavar="RUN/NODE",
                            help="a ParamMaps (Fit, Mip) or TextureSet (Quantize) artifact, e.g. runs/sbrdf-render/fit")
        parser.add_argument("--out", default=None,
                            help="folder for index.html (default views/<run>_<node> in the current directory)")
        parser.add_argument("--port", type=int, default=8000, help="localhost port to serve on (0: any free port)")
        parser.add_argument("--no-serve", action="store_true", help="only write the page")
        parser.add_argument("--sample-grid", type=int, default=16,
                            help="embed the samples of an N×N grid of texels for the click plot (0: none)")
        parser.add_argument("--max-samples", type=int, default=400, help="at most this many samples per embedded texel")
        parser.add_argument("--max-size", type=int, default=512,
                            help="larger maps are shown every k-th texel so that neither side exceeds this")

    def run(self, args) -> int:
        from sbrdf_core.registry import default_registry

        from .page import check_url, write_page  # the page's imports (zarr, dask) only when the command runs

        registry = self.registry or default_registry()  # sbrdf binds the registry of its -p plugin set
        url = str(args.artifact).rstrip("/")
        check_url(url)
        p = Path(url)
        out = Path(args.out) if args.out else Path("views") / f"{p.parent.name}_{p.name}"
        path, info = write_page(registry, url, out, sample_grid=args.sample_grid, max_samples=args.max_samples,
                                max_size=args.max_size)
        print(f"wrote {path} ({info['bytes'] / 1e6:.2f} MB in {info['write_s']:.2f} s)")
        if args.no_serve:
            return 0
        import functools
        import http.server  # here: every sbrdf invocation imports this module to declare the arguments

        handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(path.parent))
        with http.server.ThreadingHTTPServer(("127.0.0.1", args.port), handler) as server:
            print(f"serving http://127.0.0.1:{server.server_address[1]}/index.html  (Ctrl-C to stop)", flush=True)
            try:
                server.serve_forever()
            except KeyboardInterrupt:
                pass
        return 0


class PlotCommand(_Command):
    """The ``plot`` subcommand (category ``command``): :func:`sbrdf_viewer.plot.plot_views` as PNG files."""

    @staticmethod
    def add_arguments(parser) -> None:
        parser.add_argument("samples", help="a SampledReflectance artifact (e.g. runs/x/reflectance)")
        parser.add_argument("--params", default=None, help="a ParamMaps artifact whose fitted model is drawn over the samples")
        parser.add_argument("--out", default="plots", help="folder for spatial.png, hemisphere.png, incidence-plane.png")
        parser.add_argument("--texel", type=int, nargs=2, metavar=("U", "V"),
                            help="texel of views (b) and (c); default the centre")
        parser.add_argument("--wi", type=float, nargs=2, default=None, metavar=("THETA", "PHI"),
                            help="incident direction, deg; default: the texel's most populated one")
        parser.add_argument("--wo", type=float, nargs=2, default=None, metavar=("THETA", "PHI"),
                            help="exitant direction of the spatial image, deg; default: that of the pose nearest ω_i")
        parser.add_argument("--tol", type=float, default=None,
                            help="angular tolerance of views (b) and (c), deg; default 15, widened (up to 45) where "
                                 "too few samples")

    def run(self, args) -> int:
        from .plot import plot_views  # matplotlib, zarr and the data only when the command runs

        paths = plot_views(args.samples, args.out, params_url=args.params,
                           texel=tuple(args.texel) if args.texel else None, wi=tuple(args.wi) if args.wi else None,
                           wo=tuple(args.wo) if args.wo else None, tol_deg=args.tol, registry=self.registry)
        for p in paths:
            print(p)
        return 0
