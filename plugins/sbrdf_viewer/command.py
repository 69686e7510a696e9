"""``sbrdf view RUN/NODE``: write the viewer page of a fitted or quantized SBRDF and serve it on localhost.

The module imports nothing heavy: every ``sbrdf`` invocation loads it to declare the subcommand's arguments."""

from __future__ import annotations

import functools
import http.server
from pathlib import Path

from sbrdf_core.params import Param


class ViewCommand:
    """The ``view`` subcommand (category ``command``)."""

    params: tuple[Param, ...] = ()

    def __init__(self):
        self.registry = None

    def bind(self, registry) -> None:
        self.registry = registry

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
        handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(path.parent))
        with http.server.ThreadingHTTPServer(("127.0.0.1", args.port), handler) as server:
            print(f"serving http://127.0.0.1:{server.server_address[1]}/index.html  (Ctrl-C to stop)", flush=True)
            try:
                server.serve_forever()
            except KeyboardInterrupt:
                pass
        return 0
