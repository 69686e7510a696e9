"""The example plugin checked by sbrdf's conformance suites, as any third-party plugin would be.

Run from the example's directory (``pytest``) or from sbrdf's root
(``pytest docs/examples/sbrdf-example-plugin/tests``); the plugin must be
installed (``pip install -e docs/examples/sbrdf-example-plugin``) so that its
entry point is what the registry loads.
"""

from sbrdf_core.testing import BRDFModelTests, DeviceTests, PluginTests


class TestMinnaert(BRDFModelTests):
    name = "minnaert"
    configs = [{}]


class TestTurntable(DeviceTests):
    name = "turntable"
    params = {"timeout_s": 0.5, "limits_deg": [-90.0, 90.0]}
    targets = {"angle_deg": 42.5}


class TestAmbient(PluginTests):
    category = "scene-effect"
    name = "ambient"
