"""Shadow maps for the ``gl`` renderer, built only when a scene says ``shadows: true``.

One depth map per light, fitted to the scene's vertices: a perspective
frustum from a point light (which must see all geometry within 160°: a cube
map is not implemented), an orthographic box for a directional light.  The fragment shader
compares depths with a small slope-independent bias; the CPU reference casts
exact shadow rays, so the two differ only within a texel of shadow edges.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.errors import SbrdfError

SIZE = 2048
BIAS = 2e-3  # normalised depth, scaled up with the slope (tan θ, at most 20×) in the shader

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


def light_matrix(light, points: np.ndarray) -> np.ndarray:
    """World -> light clip space enclosing ``points`` (every vertex of the scene)."""
    lo, hi = points.min(0), points.max(0)
    centre = (lo + hi) / 2
    if light.type == "point":
        axis = centre - light.vector
        if np.linalg.norm(axis) < 1e-9:
            axis = np.array([0.0, 0.0, -1.0])
        view = _look(light.vector, light.vector + axis)
        q = points @ view[:3, :3].T + view[:3, 3]  # light space: looking down −z
        depth = -q[:, 2]
        front = depth > 1e-6 * max(1.0, float(depth.max(initial=1.0)))
        if not front.all():
            raise SbrdfError("gl renderer: a point light with geometry on all sides needs a cube shadow map, which is "
                             "not implemented; move the light away from the objects or use the cpu renderer")
        half = float(np.arctan(np.max(np.hypot(q[:, 0], q[:, 1]) / depth)))
        if half > np.radians(80):
            raise SbrdfError(f"gl renderer: a point light sees the scene over {2 * np.degrees(half):.0f}°; one shadow "
                             "map covers at most 160° (a cube map is not implemented): move the light away or use cpu")
        near, far = depth.min() * 0.95, depth.max() * 1.05
        f = 1 / np.tan(half * 1.02)
        proj = np.zeros((4, 4))
        proj[0, 0] = proj[1, 1] = f
        proj[2, 2], proj[2, 3], proj[3, 2] = (far + near) / (near - far), 2 * far * near / (near - far), -1
        return proj @ view
    radius = float(np.linalg.norm(hi - lo)) / 2 + 1e-6
    view = _look(centre + light.vector * radius * 2, centre)
    q = points @ view[:3, :3].T + view[:3, 3]
    x0, y0, z0 = q.min(0)
    x1, y1, z1 = q.max(0)
    proj = np.eye(4)
    proj[0, 0], proj[0, 3] = 2 / (x1 - x0 + 1e-9), -(x1 + x0) / (x1 - x0 + 1e-9)
    proj[1, 1], proj[1, 3] = 2 / (y1 - y0 + 1e-9), -(y1 + y0) / (y1 - y0 + 1e-9)
    near, far = -z1 - 1e-3 * radius, -z0 + 1e-3 * radius  # depths along −z
    proj[2, 2], proj[2, 3] = -2 / (far - near), -(far + near) / (far - near)
    return proj @ view


class ShadowMaps:
    def __init__(self, ctx, scene, meshes: dict):
        import moderngl

        self.ctx = ctx
        points = np.concatenate([m.positions for m in meshes.values()])
        self.matrices = [light_matrix(lt, points).astype("f4") for lt in scene.lights]
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
