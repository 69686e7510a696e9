"""Built-in capture sources: ``synthetic`` (texel-aligned simulation) and ``folder`` (sbrdf-capture/1 folders).

Each source's parameters are declared in :mod:`.declarations`, which imports
no source.  The capture-folder format itself is in the library layer
(:mod:`sbrdf_lib.capture_folder`, with the response-curve tables in
:mod:`sbrdf_lib.response`), so rigs and simulators in other packages write
what ``folder`` reads; HDR merge, response recovery and colour calibration
live beside the reader (``hdr``, ``response``, ``colour``).
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_captures():
    return [
        PluginSpec(
            "folder",
            "sbrdf_capture.folder:FolderCapture",
            params=declarations.FOLDER,
            summary="Read an sbrdf-capture/1 folder (EXR, 8/16-bit PNG/TIFF): validated, HDR-merged, one pose at a time",
        ),
        PluginSpec(
            "synthetic",
            "sbrdf_capture.synthetic:SyntheticCapture",
            params=declarations.SYNTHETIC,
            summary="Simulated texel-aligned capture of a procedural material of any BRDF model",
        ),
    ]
