"""Built-in BRDF models.  Each model is one module named as registered: its doc at the top, the per-texel
parameters, eval, Jacobian and GLSL, and its ``sbrdf_brdf_models`` registration at the bottom; pyproject's
``[project.entry-points.sbrdf]`` lists each module as a plugin of its own."""
