"""sbrdf: measured surface appearance as declarative dask/zarr graphs.

The core knows node kinds, artifacts and plugins, and no BRDF model, device or
renderer by name.  Where things live:

- ``hookspecs.py``  the plugin author's contract (read this first)
- ``registry.py``   plugin discovery through the ``sbrdf`` entry-point group
- ``params.py``     how a plugin declares its parameters
- ``artifacts.py``  the typed artifacts that flow between nodes
- ``types.py``      the data types the contract hands to plugins and back
- ``store/``        how an artifact lives in zarr, chunk by chunk; integrity, the store's lock
- ``graph.py``      YAML -> validated graph, errors with file and line
- ``runner.py``     executes a graph with dask: caching, resume, progress
- ``nodes/``        one module per node kind
- ``brdf.py``       the BRDF-model protocol
- ``contracts.py``  one Protocol per kind of contribution, and their optional members
- ``extras.py``     optional dependencies: ``require`` names the extra to install
- ``_dask_compat.py`` every private dask name used, in one place
"""

from importlib.metadata import PackageNotFoundError, version

try:  # the version is written once, in pyproject.toml
    __version__ = version("sbrdf")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
