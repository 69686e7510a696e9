"""Shadow maps for the ``gl`` renderer, built only when a scene says ``shadows: true``.

One depth map per light, rendered from the light over the scene's bounding
sphere: a perspective frustum for a point light (which must lie outside that
sphere), an orthographic box for a directional light.  The fragment shader
compares depths with a small slope-independent bias; the CPU reference casts
exact shadow rays, so the two differ only within a texel of shadow edges.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.errors import SbrdfError

SIZE = 2048
BIAS = 2e-3  # in normalised depth; acne-free on the built-in shapes at 2048²

DEPTH_VS = """#version 330
uniform mat4 u_mvp;
in vec3 in_pos;
void main() { gl_Position = u_mvp * vec4(in_pos, 1.0); }
"""
DEPTH_FS = """#version 330
void main() {}
"""


def _look(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    f = target - eye
    f = f / np.linalg.norm(f)
    up = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = r, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def light_matrix(light, centre: np.ndarray, radius: float) -> np.ndarray:
    """World -> light clip space covering the sphere (centre, radius)."""
    if light.type == "point":
        d = float(np.linalg.norm(light.vector - centre))
        if d <= radius * 1.01:
            raise SbrdfError("gl renderer: shadows from a point light inside the scene's bounding sphere need a cube "
                             "shadow map, which is not implemented; move the light out or use the cpu renderer")
        half = np.arcsin(min(radius * 1.01 / d, 0.999))
        near, far = max(d - radius * 1.01, d * 1e-3), d + radius * 1.01
        f = 1 / np.tan(half)
        proj = np.zeros((4, 4))
        proj[0, 0] = proj[1, 1] = f
        proj[2, 2], proj[2, 3], proj[3, 2] = (far + near) / (near - far), 2 * far * near / (near - far), -1
        return proj @ _look(light.vector, centre)
    eye = centre + light.vector * radius * 2
    r = radius * 1.01
    proj = np.diag([1 / r, 1 / r, -1 / (2 * r), 1.0])
    proj[2, 3] = -(radius * 2) / (2 * r)  # maps distance [radius, 3 radius] from the eye to [-1, 1]
    return proj @ _look(eye, centre)


class ShadowMaps:
    def __init__(self, ctx, scene, meshes: dict):
        import moderngl

        self.ctx = ctx
        centre, radius = scene.bounds()
        self.matrices = [light_matrix(lt, centre, radius).astype("f4") for lt in scene.lights]
        self.prog = ctx.program(vertex_shader=DEPTH_VS, fragment_shader=DEPTH_FS)
        self.vaos, self.buffers, self.maps, self.fbos = [], [], [], []
        for mesh in meshes.values():
            vbo = ctx.buffer(mesh.positions.astype("f4").tobytes())
            ibo = ctx.buffer(mesh.indices.astype("u4").tobytes())
            self.buffers += [vbo, ibo]
            self.vaos.append(ctx.vertex_array(self.prog, [(vbo, "3f", "in_pos")], ibo))
        for _ in scene.lights:
            depth = ctx.depth_texture((SIZE, SIZE))
            depth.compare_func = "<="
            depth.filter = (moderngl.LINEAR, moderngl.LINEAR)  # 2x2 percentage-closer filtering
            self.maps.append(depth)
            self.fbos.append(ctx.framebuffer(depth_attachment=depth))

    def render(self) -> None:
        import moderngl

        self.ctx.enable(moderngl.DEPTH_TEST)
        for fbo, m in zip(self.fbos, self.matrices):
            fbo.use()
            fbo.clear(depth=1.0)
            self.prog["u_mvp"].write(m.T.tobytes())
            for vao in self.vaos:
                vao.render(moderngl.TRIANGLES)

    def set_uniforms(self, prog, first_unit: int) -> None:
        prog["u_shadow_mvp"].write(np.stack([m.T for m in self.matrices]).tobytes())
        prog["u_shadow"].write(np.arange(first_unit, first_unit + len(self.maps), dtype="i4").tobytes())

    def use(self, first_unit: int) -> None:
        for k, depth in enumerate(self.maps):
            depth.use(first_unit + k)

    def release(self) -> None:
        for obj in self.fbos + self.maps + self.vaos + self.buffers + [self.prog]:
            obj.release()
