"""sbrdf_lib: the public library layer, the code plugins share.

Built-in and third-party plugins import only :mod:`sbrdf_core`, this package
and their own package; anything else from another plugin goes through the
registry (``registry.create(category, name, params)``).  Modules here import
only :mod:`sbrdf_core` and :mod:`sbrdf_lib`; each has a module docstring and
``__all__``, and heavy third-party imports (pyserial, moderngl, cv2) sit at
module level only in the modules that are about them.

This file imports nothing, so importing one module never imports the others.

Fitting:

:mod:`sbrdf_lib.lm`
    The batched Levenberg–Marquardt every fitter shares (``fit_model``,
    ``levenberg_marquardt``), Sobol candidate starts, robust losses.
:mod:`sbrdf_lib.convert`
    Any model's per-texel BRDF refitted to GGX and read as glTF
    metallic-roughness, with the conversion's error at held-out directions
    (the exporters share it).

Rendering:

:mod:`sbrdf_lib.gl`
    OpenGL through moderngl's EGL backend: contexts, GLSL expressions of
    parameter maps, the ``Drawer`` the ``gl`` renderer and scene effects share.
:mod:`sbrdf_lib.surface`
    Surface frames, shapes, tessellation and ray casting (``Hits``, ``cast``,
    ``local_frame``) for the ``cpu`` renderer and effects.
:mod:`sbrdf_lib.mesh`
    The one OBJ reader.
:mod:`sbrdf_lib.scene`
    The scene-file schema and loader; plugins add keys through ``sbrdf_scene_keys``.

Acquisition:

:mod:`sbrdf_lib.serial`
    Serial device drivers: :class:`~sbrdf_lib.serial.SerialLink`,
    :class:`~sbrdf_lib.serial.MotorController`, the ``DeviceError`` family and
    the :class:`~sbrdf_lib.serial.PtySimulator` base (needs pyserial).
:mod:`sbrdf_lib.capture_folder`
    The ``sbrdf-capture/1`` folder format: manifest parsing and validation,
    the crash-safe :class:`~sbrdf_lib.capture_folder.CaptureFolderWriter`,
    journal, image decoding, the CaptureSet attributes of a manifest.
:mod:`sbrdf_lib.response`
    Camera response curves as tables (:class:`~sbrdf_lib.response.ResponseCurve`).
:mod:`sbrdf_lib.rig_geometry`
    Kinematics of the four-motor gonioreflectometer
    (:class:`~sbrdf_lib.rig_geometry.RigGeometry`, ``forward``, ``inverse``).
:mod:`sbrdf_lib.mesostructure`
    Height field with albedo for simulated cameras (shadowing, masking).
:mod:`sbrdf_lib.patterns`
    Procedural ground-truth parameter maps.

See ``docs/architecture.md`` for the import rule.
"""

__all__: list[str] = []
