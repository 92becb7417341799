"""Writes assets/teapot_draco.glb: assets/teapot.obj as a Draco-compressed glTF binary
(KHR_draco_mesh_compression), so that a clone without the development data set still has a real
Draco file to test the loaders with (LittlestTokyo, the data set's Draco scene, is 4 MB).

    .venv/bin/python tests/make_draco_asset.py        # needs DracoPy and pygltflib

The mesh keeps teapot.obj's vertex and face order (DracoPy ``preserve_order``); positions are
quantized to 16 bits over the mesh's bounding box, so each coordinate is within extent / 2^16 of
the OBJ's.  The file holds only the compressed primitive (no uncompressed fallback), as the
extension's ``extensionsRequired`` form says.
"""

import struct
from pathlib import Path

import numpy as np

ASSETS = Path(__file__).resolve().parents[1] / "assets"
BITS = 16


def read_obj(path):
    v, f = [], []
    for line in path.read_text().splitlines():
        p = line.split()
        if p and p[0] == "v":
            v.append([float(x) for x in p[1:4]])
        elif p and p[0] == "f":
            f.append([int(x.split("/")[0]) - 1 for x in p[1:4]])
    return np.array(v, np.float32), np.array(f, np.uint32)


def main():
    import json

    import DracoPy

    v, f = read_obj(ASSETS / "teapot.obj")
    blob = DracoPy.encode(v, f, quantization_bits=BITS, compression_level=7, preserve_order=True)
    blob += b"\0" * (-len(blob) % 4)
    gltf = {
        "asset": {"version": "2.0", "generator": "gridrt tests/make_draco_asset.py (DracoPy)"},
        "extensionsUsed": ["KHR_draco_mesh_compression"],
        "extensionsRequired": ["KHR_draco_mesh_compression"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "teapot"}],
        "meshes": [{"name": "teapot", "primitives": [{
            "attributes": {"POSITION": 0}, "indices": 1, "mode": 4,
            "extensions": {"KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": 0}}},
        }]}],
        "accessors": [
            {"componentType": 5126, "count": int(len(v)), "type": "VEC3",
             "min": v.min(axis=0).tolist(), "max": v.max(axis=0).tolist()},
            {"componentType": 5125, "count": int(f.size), "type": "SCALAR"},
        ],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(blob)}],
        "buffers": [{"byteLength": len(blob)}],
    }
    js = json.dumps(gltf, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    out = b"".join([
        struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(js) + 8 + len(blob)),
        struct.pack("<II", len(js), 0x4E4F534A), js,
        struct.pack("<II", len(blob), 0x004E4942), blob,
    ])
    (ASSETS / "teapot_draco.glb").write_bytes(out)
    print(f"wrote {ASSETS / 'teapot_draco.glb'}: {len(v)} vertices, {len(f)} triangles, {len(out)} bytes")


if __name__ == "__main__":
    main()
