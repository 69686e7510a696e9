"""gltf: a fitted material as glTF 2.0 — a textured quad with metallic-roughness PBR textures.

Conversion (lazy, per texel tile, :func:`sbrdf_lib.convert.to_gltf_pbr_blocks`):
each texel's BRDF is refitted to GGX (the ``cook-torrance`` model, GGX
facets) with a specular weight, cosine-weighted, on a fixed set of direction
pairs, and read as glTF's metallic-roughness BRDF (Appendix B) with
``KHR_materials_specular``; ``error`` is the relative RMS of glTF's BRDF
against the source on held-out pairs (docs/interchange.md).  Texels whose
error is above ``flag_error`` are flagged: ``<name>_flagged.png`` (255 where
flagged) and ``<name>_conversion_error.exr`` are written beside the glTF
(not referenced by it), and the material's ``extras.sbrdf`` counts them.

With ``source: samples`` and the Export node's ``samples`` input, glTF's GGX
is fitted to each texel's measured reflectance samples instead
(:func:`sbrdf_lib.convert.samples_to_gltf`, isotropic, the same LM and the
same reading as glTF); ``error`` is then glTF's BRDF against the samples
(cos θ_i cos θ_o weighted relative RMS).  ``extras.sbrdf.fitted_to`` says which.

Files (``format: gltf``): ``<name>.gltf``, ``<name>.bin`` (geometry) and the
PNG textures; ``format: glb``: one ``<name>.glb`` with everything embedded.

- ``baseColorTexture``: ``<name>_base_color.png``, 8-bit sRGB (RGBA with
  ``alphaMode: MASK``, cutoff 0.5, when the material has a transparency map).
- ``metallicRoughnessTexture``: ``<name>_metallic_roughness.png``, 8-bit
  linear, roughness in G, metallic in B (R = 255, unused: no occlusion).
- ``KHR_materials_specular`` (only when some texel's F0 is not the default
  dielectric 0.04, or its specular weight is not 1): ``<name>_specular.png``,
  RGB = specular colour (sRGB, as the extension says) / ``specularColorFactor``
  (the material's largest F0c/0.04, grey, up to 25: the extension clamps
  0.04 · specularColor at 1, not the factor), A = specularFactor (linear).
- ``KHR_materials_anisotropy`` (only when the source model may be anisotropic
  and some texel reads better with it, :mod:`sbrdf_lib.convert` step 5):
  ``<name>_anisotropy.png``, 8-bit linear, RG = the direction (cos φ, sin φ)
  in the tangent frame mapped from [−1, 1] to [0, 1], B = strength;
  ``anisotropyStrength`` 1, ``anisotropyRotation`` 0.  The quad then carries
  TANGENT (+X, w = 1), so the direction's frame is the sample's x and y.

Geometry and convention: the sample is a ``size_mm`` quad (metres in glTF)
centred at the origin in the XZ plane, facing +Y (glTF is Y-up): the sample's
+x (texel u) is glTF +X, its +y (texel v) is glTF −Z, its normal +Z is glTF
+Y; NORMAL is (0, 1, 0); TANGENT (+X) is written with anisotropy only (a
viewer's MikkTSpace tangent from the uvs is the same +X, bitangent −Z, the
sample's x and y).  TEXCOORD_0 = (u, v) in [0, 1]: texel row 0 (v = 0,
the first row of every image written) is at glTF z = +height/2.  Samplers are
linear, clamped to the edge.  Each material's ``extras.sbrdf`` records the
source model, the texel grid and the conversion's error summary.

:func:`read_gltf` reads a file written here back into the per-texel glTF maps
and :func:`gltf_maps_to_ggx` turns them into cook-torrance GGX parameters (or
``ggx-anisotropic`` ones where the file has anisotropy), for round trips.
"""

from __future__ import annotations

import base64
import json
import os
import struct
from typing import Any

import numpy as np

from sbrdf_lib.convert import DIELECTRIC_F0, GLTF_MAPS, anisotropic_model, ggx_model, to_gltf_pbr_blocks

from .declarations import GLTF

#: Texels whose specular colour or factor differ from the default dielectric by more than this need the extension.
SPECULAR_TOLERANCE = 0.02
#: Some texel's anisotropy strength above this writes ``KHR_materials_anisotropy`` (one 8-bit step is 0.004).
ANISOTROPY_TOLERANCE = 0.02
_FLOAT, _USHORT = 5126, 5123
_ARRAY, _ELEMENTS = 34962, 34963
_LINEAR, _LINEAR_MIPMAP, _CLAMP = 9729, 9987, 33071


class GLTFExporter:
    """glTF 2.0 metallic-roughness textures of a GGX conversion fit, on a quad the sample's size."""

    params = GLTF

    def __init__(self, *, format: str = "gltf", name: str = "material", tile: int = 64, starts: int = 1,
                 iterations: int = 8, anisotropy: bool = True, flag_error: float = 0.25,
                 max_theta_deg: float = 70.0, source: str = "params"):
        if format not in ("gltf", "glb"):
            raise ValueError(f"gltf: format must be 'gltf' or 'glb', got {format!r}")
        if source not in ("params", "samples"):
            raise ValueError(f"gltf: source must be 'params' or 'samples', got {source!r}")
        self.source = source
        self.format = format
        self.name = name
        self.tile = tile
        self.starts = starts
        self.iterations = iterations
        self.anisotropy = anisotropy
        self.flag_error = flag_error
        self.max_theta_deg = max_theta_deg
        self._registry = None

    def bind(self, registry) -> None:
        self._registry = registry

    def _ggx(self):
        return ggx_model(self._registry)

    def convert(self, material):
        import dask.array as da

        if self.source == "samples":
            return self._fit_samples(material)
        params = {p.name: da.asarray(material.params[p.name]).rechunk((self.tile, self.tile, -1))
                  for p in material.model.parameters}
        aniso = anisotropic_model(self._registry) if self.anisotropy else None
        maps = to_gltf_pbr_blocks(material.model, params, self._ggx(), starts=self.starts, iterations=self.iterations,
                                  anisotropic=aniso, flag_error=self.flag_error, max_theta_deg=self.max_theta_deg)
        return {**maps, "conversion_error": maps["error"], "flagged": (maps["error"] > self.flag_error).astype(np.float32)}

    def _fit_samples(self, material):
        """glTF's GGX fitted to the reflectance samples (:func:`sbrdf_lib.convert.samples_to_gltf_blocks`)."""
        from sbrdf_core.errors import SbrdfError
        from sbrdf_lib.convert import samples_to_gltf_blocks

        samples = getattr(material, "samples", None)
        if samples is None:
            raise SbrdfError("gltf: source 'samples' fits glTF's GGX to the reflectance samples: give the Export node "
                             "its samples input (in: {material: fit, samples: <the Fit node's samples>})")
        maps = samples_to_gltf_blocks(samples.array("f_r"), samples.array("valid"), samples.read("light_pos"),
                                      samples.read("camera_pos"), tuple(samples.attrs["texels"]),
                                      tuple(samples.attrs["size_mm"]), self._ggx(), starts=self.starts,
                                      iterations=self.iterations, max_theta_deg=self.max_theta_deg)
        return {**maps, "conversion_error": maps["error"], "flagged": (maps["error"] > self.flag_error).astype(np.float32)}

    def write(self, directory, maps, material):
        d = directory
        alpha = None
        if getattr(material, "alpha", None) is not None:
            alpha = np.asarray(material.alpha, np.float64)
        error = maps.get("conversion_error", maps.get("error"))
        summary: dict = {}
        if error is not None:
            e = np.asarray(error, np.float64)
            flagged = e[..., 0] > self.flag_error
            e = e[np.isfinite(e)]
            if e.size:
                summary = {"error_mean": float(e.mean()), "error_median": float(np.median(e)),
                           "error_p95": float(np.percentile(e, 95)), "error_max": float(e.max()),
                           "flag_error": float(self.flag_error), "flagged": int(flagged.sum())}
        extras = {"model": material.model.name, "source": material.source, "texels": [int(x) for x in material.texels],
                  "size_mm": [float(x) for x in material.size_mm], "fitted_to": self.source, **summary}
        files, info = write_gltf(d, self.name, {k: np.asarray(maps[k]) for k in GLTF_MAPS if k in maps}, material.size_mm,
                                 binary=self.format == "glb", alpha=alpha, extras=extras)
        if error is not None:  # beside the glTF, not in it: the per-texel error a viewer cannot show
            from sbrdf_core.io import write_exr, write_png

            e = np.asarray(error, np.float32)
            write_exr(os.path.join(d, f"{self.name}_conversion_error.exr"), np.repeat(e, 3, axis=-1))
            write_png(os.path.join(d, f"{self.name}_flagged.png"), ((e[..., 0] > self.flag_error) * 255).astype(np.uint8))
            files += [f"{self.name}_conversion_error.exr", f"{self.name}_flagged.png"]
        return {"files": files, "format": "glb" if self.format == "glb" else "gltf", "fitted_to": self.source, **info,
                **{k: summary[k] for k in ("flag_error", "flagged") if k in summary}}


def _srgb8(x: np.ndarray) -> np.ndarray:
    from sbrdf_core.io import linear_to_srgb8

    return linear_to_srgb8(np.clip(np.nan_to_num(x), 0.0, 1.0))


def _linear8(x: np.ndarray) -> np.ndarray:
    return np.round(np.clip(np.nan_to_num(x), 0.0, 1.0) * 255).astype(np.uint8)


def _png_bytes(image: np.ndarray) -> bytes:
    import cv2

    img = np.asarray(image)
    if img.ndim == 3 and img.shape[-1] in (3, 4):
        img = img[..., [2, 1, 0, 3][: img.shape[-1]]]  # OpenCV stores BGR(A)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img))
    if not ok:
        raise ValueError("cannot encode PNG")
    return buf.tobytes()


def textures(maps: dict, alpha: np.ndarray | None = None) -> tuple[dict[str, np.ndarray], dict]:
    """The PNG images (8-bit ``(V, U, C)``) and the material JSON for the per-texel glTF maps.

    Returns ``({image name: uint8 array}, material dict with texture references by image name)``.
    """
    bc, m = np.asarray(maps["base_color"]), np.asarray(maps["metallic"])[..., :1]
    rough = np.asarray(maps["roughness"])[..., :1]
    spec, spec_col = np.asarray(maps["specular"])[..., :1], np.asarray(maps["specular_color"])
    images: dict[str, np.ndarray] = {}
    base = _srgb8(bc)
    pbr: dict[str, Any] = {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 1.0, "roughnessFactor": 1.0,
           "baseColorTexture": "base_color", "metallicRoughnessTexture": "metallic_roughness"}
    material: dict[str, Any] = {"pbrMetallicRoughness": pbr, "doubleSided": False}
    if alpha is not None:
        base = np.concatenate([base, _linear8(np.asarray(alpha)[..., :1])], axis=-1)
        material.update(alphaMode="MASK", alphaCutoff=0.5)
    images["base_color"] = base
    images["metallic_roughness"] = np.concatenate([np.full_like(_linear8(rough), 255), _linear8(rough), _linear8(m)],
                                                  axis=-1)
    dielectric = m[..., 0] < 0.5
    off = (np.abs(spec_col - 1.0).max(axis=-1) > SPECULAR_TOLERANCE) | (np.abs(spec[..., 0] - 1.0) > SPECULAR_TOLERANCE)
    if (off & dielectric).any():
        scale = float(max(1.0, np.nanmax(np.where(dielectric[..., None], spec_col, 0.0))))
        # specularFactor carries the largest weight, the texture the ratio: a weak specular (s ~ 0.002) keeps
        # its 8-bit steps instead of rounding to 0 or 1/255
        weight = float(np.nanmax(np.where(dielectric, spec[..., 0], 0.0)))
        weight = round(weight, 6) if weight > 0 else 1.0
        ratio = np.where(dielectric[..., None], spec / weight, 1.0)
        images["specular"] = np.concatenate([_srgb8(spec_col / scale), _linear8(ratio)], axis=-1)
        material["extensions"] = {"KHR_materials_specular": {
            "specularFactor": weight, "specularColorFactor": [scale, scale, scale],
            "specularTexture": "specular", "specularColorTexture": "specular"}}
    aniso = maps.get("anisotropy")
    if aniso is not None and (np.asarray(aniso)[..., 2] > ANISOTROPY_TOLERANCE).any():
        a = np.asarray(aniso, np.float64)
        images["anisotropy"] = np.concatenate([_linear8(a[..., :2] * 0.5 + 0.5), _linear8(a[..., 2:3])], axis=-1)
        material.setdefault("extensions", {})["KHR_materials_anisotropy"] = {
            "anisotropyStrength": 1.0, "anisotropyRotation": 0.0, "anisotropyTexture": "anisotropy"}
    return images, material


def _quad(size_mm, tangents: bool = False) -> dict[str, np.ndarray]:
    w, h = float(size_mm[0]) / 1000.0, float(size_mm[1]) / 1000.0
    x, z = w / 2, h / 2
    quad: dict[str, np.ndarray] = {
        "POSITION": np.array([[-x, 0, z], [x, 0, z], [x, 0, -z], [-x, 0, -z]], np.float32),
        "NORMAL": np.tile(np.array([0, 1, 0], np.float32), (4, 1)),
        "TEXCOORD_0": np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
        "indices": np.array([0, 1, 2, 0, 2, 3], np.uint16),
    }
    if tangents:  # the sample's x, right-handed with the normal and the bitangent (its y, glTF -Z)
        quad["TANGENT"] = np.tile(np.array([1, 0, 0, 1], np.float32), (4, 1))
    return quad


def build_gltf(name: str, maps: dict, size_mm, *, binary: bool, alpha=None, extras=None):
    """The glTF JSON, the binary buffer and the PNG files (``{file name: bytes}``, empty for GLB)."""
    images, material = textures(maps, alpha)
    quad = _quad(size_mm, tangents="KHR_materials_anisotropy" in material.get("extensions", {}))
    blob = bytearray()
    views, accessors = [], []

    def add_view(data: bytes, target=None) -> int:
        while len(blob) % 4:
            blob.append(0)
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        blob.extend(data)
        views.append(view)
        return len(views) - 1

    types = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
    attributes = {}
    for key in ("POSITION", "NORMAL", "TANGENT", "TEXCOORD_0"):
        if key not in quad:
            continue
        a = quad[key]
        acc = {"bufferView": add_view(a.tobytes(), _ARRAY), "componentType": _FLOAT, "count": len(a),
               "type": types[a.shape[1]]}
        if key == "POSITION":
            acc.update(min=a.min(axis=0).tolist(), max=a.max(axis=0).tolist())
        accessors.append(acc)
        attributes[key] = len(accessors) - 1
    idx = quad["indices"]
    accessors.append({"bufferView": add_view(idx.tobytes(), _ELEMENTS), "componentType": _USHORT, "count": len(idx),
                      "type": "SCALAR"})
    files, image_json, texture_of = {}, [], {}
    for k, img in images.items():
        png = _png_bytes(img)
        if binary:
            image_json.append({"bufferView": add_view(png), "mimeType": "image/png", "name": k})
        else:
            fname = f"{name}_{k}.png"
            files[fname] = png
            image_json.append({"uri": fname, "name": k})
        texture_of[k] = len(image_json) - 1
    pbr = material["pbrMetallicRoughness"]
    for key in ("baseColorTexture", "metallicRoughnessTexture"):
        pbr[key] = {"index": texture_of[pbr[key]]}
    used = []
    spec = material.get("extensions", {}).get("KHR_materials_specular")
    if spec is not None:
        used.append("KHR_materials_specular")
        for key in ("specularTexture", "specularColorTexture"):
            spec[key] = {"index": texture_of[spec[key]]}
    aniso = material.get("extensions", {}).get("KHR_materials_anisotropy")
    if aniso is not None:
        used.append("KHR_materials_anisotropy")
        aniso["anisotropyTexture"] = {"index": texture_of[aniso["anisotropyTexture"]]}
    material["name"] = name
    if extras:
        material["extras"] = {"sbrdf": extras}
    while len(blob) % 4:
        blob.append(0)
    buffer: dict[str, Any] = {"byteLength": len(blob)}
    if not binary:
        buffer["uri"] = f"{name}.bin"
    doc = {
        "asset": {"version": "2.0", "generator": "sbrdf gltf exporter"},
        "scene": 0,
        "scenes": [{"name": name, "nodes": [0]}],
        "nodes": [{"name": "sample", "mesh": 0}],
        "meshes": [{"name": "sample", "primitives": [{"attributes": attributes, "indices": len(accessors) - 1,
                                                      "material": 0, "mode": 4}]}],
        "materials": [material],
        "samplers": [{"magFilter": _LINEAR, "minFilter": _LINEAR_MIPMAP, "wrapS": _CLAMP, "wrapT": _CLAMP}],
        "textures": [{"sampler": 0, "source": i} for i in range(len(image_json))],
        "images": image_json,
        "buffers": [buffer],
        "bufferViews": views,
        "accessors": accessors,
    }
    if used:
        doc["extensionsUsed"] = used
    return doc, bytes(blob), files


def glb_bytes(doc: dict, blob: bytes) -> bytes:
    """A GLB container: header, JSON chunk (space-padded), BIN chunk (zero-padded)."""
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    blob = blob + b"\0" * (-len(blob) % 4)
    total = 12 + 8 + len(js) + 8 + len(blob)
    return (struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(js), 0x4E4F534A) + js
            + struct.pack("<II", len(blob), 0x004E4942) + blob)


def write_gltf(directory: str, name: str, maps: dict, size_mm, *, binary: bool = False, alpha=None,
               extras=None) -> tuple[list[str], dict]:
    """Write ``<name>.gltf`` + ``.bin`` + PNGs (or ``<name>.glb``) in ``directory``; ``(files, attributes)``."""
    doc, blob, pngs = build_gltf(name, maps, size_mm, binary=binary, alpha=alpha, extras=extras)
    os.makedirs(directory, exist_ok=True)
    if binary:
        with open(os.path.join(directory, f"{name}.glb"), "wb") as f:
            f.write(glb_bytes(doc, blob))
        files = [f"{name}.glb"]
    else:
        with open(os.path.join(directory, f"{name}.bin"), "wb") as f:
            f.write(blob)
        for fname, data in pngs.items():
            with open(os.path.join(directory, fname), "wb") as f:
                f.write(data)
        with open(os.path.join(directory, f"{name}.gltf"), "w") as f:
            json.dump(doc, f, indent=1)
        files = [f"{name}.gltf", f"{name}.bin", *pngs]
    info = {"extensions": doc.get("extensionsUsed", [])}
    spec = doc["materials"][0].get("extensions", {}).get("KHR_materials_specular")
    if spec:
        info["specular_color_factor"] = spec["specularColorFactor"][0]
        info["specular_factor"] = spec["specularFactor"]
    return files, info


# -- reading back ---------------------------------------------------------------------------------------------


def _read_doc(path: str) -> tuple[dict, bytes | None]:
    with open(path, "rb") as f:
        data = f.read()
    if data[:4] == b"glTF":
        _, _, total = struct.unpack_from("<III", data, 0)
        off, doc, blob = 12, None, None
        while off < total:
            length, kind = struct.unpack_from("<II", data, off)
            chunk = data[off + 8: off + 8 + length]
            if kind == 0x4E4F534A:
                doc = json.loads(chunk)
            elif kind == 0x004E4942:
                blob = chunk
            off += 8 + length
        if doc is None:
            raise ValueError(f"{path}: a GLB file without its JSON chunk")
        return doc, blob
    return json.loads(data), None


def _image(doc, index, directory, blob) -> np.ndarray:
    import cv2

    im = doc["images"][doc["textures"][index]["source"]]
    if "bufferView" in im:
        v = doc["bufferViews"][im["bufferView"]]
        data = blob[v.get("byteOffset", 0): v.get("byteOffset", 0) + v["byteLength"]]
    elif im["uri"].startswith("data:"):
        data = base64.b64decode(im["uri"].split(",", 1)[1])
    else:
        with open(os.path.join(directory, im["uri"]), "rb") as f:
            data = f.read()
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"texture {index} ({im.get('uri', 'embedded')}) is not an image OpenCV can decode")
    if img.ndim == 3:
        img = img[..., [2, 1, 0, 3][: img.shape[-1]]]
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    return img.astype(np.float64) / scale


def _srgb_to_linear(s: np.ndarray) -> np.ndarray:
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def read_gltf(path: str) -> dict[str, np.ndarray]:
    """The per-texel glTF maps (:data:`sbrdf_lib.convert.GLTF_MAPS`, linear, ``(V, U, C)``) of the first material.

    Textures are decoded (sRGB for colour) and multiplied by their factors, as a
    glTF renderer does; a missing texture is its factor alone.
    """
    doc, blob = _read_doc(path)
    directory = os.path.dirname(path)
    mat = doc["materials"][0]
    pbr = mat.get("pbrMetallicRoughness", {})
    bcf = np.asarray(pbr.get("baseColorFactor", [1, 1, 1, 1]), np.float64)
    shape = None
    out = {}
    if "baseColorTexture" in pbr:
        img = _image(doc, pbr["baseColorTexture"]["index"], directory, blob)
        out["base_color"] = _srgb_to_linear(img[..., :3]) * bcf[:3]
        shape = img.shape[:2]
    if "metallicRoughnessTexture" in pbr:
        img = _image(doc, pbr["metallicRoughnessTexture"]["index"], directory, blob)
        out["roughness"] = img[..., 1:2] * pbr.get("roughnessFactor", 1.0)
        out["metallic"] = img[..., 2:3] * pbr.get("metallicFactor", 1.0)
        shape = shape or img.shape[:2]
    shape = shape or (1, 1)
    out.setdefault("base_color", np.broadcast_to(bcf[:3], shape + (3,)).copy())
    out.setdefault("roughness", np.full(shape + (1,), pbr.get("roughnessFactor", 1.0)))
    out.setdefault("metallic", np.full(shape + (1,), pbr.get("metallicFactor", 1.0)))
    spec = mat.get("extensions", {}).get("KHR_materials_specular", {})
    sf = float(spec.get("specularFactor", 1.0))
    scf = np.asarray(spec.get("specularColorFactor", [1.0, 1.0, 1.0]), np.float64)
    out["specular"] = np.full(shape + (1,), sf)
    out["specular_color"] = np.broadcast_to(scf, shape + (3,)).copy()
    if "specularTexture" in spec:
        out["specular"] = out["specular"] * _image(doc, spec["specularTexture"]["index"], directory, blob)[..., 3:4]
    if "specularColorTexture" in spec:
        img = _image(doc, spec["specularColorTexture"]["index"], directory, blob)
        out["specular_color"] = out["specular_color"] * _srgb_to_linear(img[..., :3])
    aniso = mat.get("extensions", {}).get("KHR_materials_anisotropy")
    if aniso is not None:  # direction rotated by anisotropyRotation, strength × anisotropyStrength
        rot = float(aniso.get("anisotropyRotation", 0.0))
        direction = np.broadcast_to(np.array([1.0, 0.0]), shape + (2,))
        strength = np.full(shape + (1,), float(aniso.get("anisotropyStrength", 0.0)))
        if "anisotropyTexture" in aniso:
            img = _image(doc, aniso["anisotropyTexture"]["index"], directory, blob)
            direction = img[..., :2] * 2.0 - 1.0
            strength = strength * img[..., 2:3]
        phi = np.arctan2(direction[..., 1:2], direction[..., 0:1]) + rot
        out["anisotropy"] = np.concatenate([np.cos(phi), np.sin(phi), strength], axis=-1)
    return out


def gltf_maps_to_ggx(maps: dict) -> dict[str, np.ndarray]:
    """glTF maps -> cook-torrance GGX ``rho_d``, ``f0``, ``alpha`` (same leading shape).

    ρ_d = (1 − metallic)·baseColor/π (glTF's (1 − max F) diffuse weight has no
    counterpart in cook-torrance and is dropped), F0 = lerp(min(0.04·specularColor, 1)·specular,
    baseColor, metallic), α = roughness² (floored at cook-torrance's 1e-3).  With an
    ``anisotropy`` map (``KHR_materials_anisotropy``): ``ggx-anisotropic``'s ``alpha_t`` =
    mix(α, 1, strength²), ``alpha_b`` = α and ``phi`` = the direction's angle instead of ``alpha``.
    """
    bc, m = np.asarray(maps["base_color"], np.float64), np.asarray(maps["metallic"], np.float64)[..., :1]
    s = np.asarray(maps["specular"], np.float64)[..., :1]
    f0_d = np.minimum(DIELECTRIC_F0 * np.asarray(maps["specular_color"], np.float64), 1.0) * s
    rough2 = np.asarray(maps["roughness"], np.float64)[..., :1] ** 2
    out = {"rho_d": (1.0 - m) * bc / np.pi, "f0": (1.0 - m) * f0_d + m * bc, "alpha": np.maximum(rough2, 1e-3)}
    if "anisotropy" in maps:
        a = np.asarray(maps["anisotropy"], np.float64)
        strength = np.clip(a[..., 2:3], 0.0, 1.0)
        out["alpha_b"] = out.pop("alpha")
        out["alpha_t"] = np.clip(rough2 + (1.0 - rough2) * strength**2, 1e-3, 1.0)
        out["phi"] = np.arctan2(a[..., 1:2], a[..., 0:1])
    return out
