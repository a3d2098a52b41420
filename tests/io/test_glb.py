"""scene.glb read back by the glTF 2.0 binary layout itself (header, 4-byte aligned JSON and BIN chunks,
accessors), independent of any reader library; tests/io/test_exports.py also loads it with trimesh."""

import json
import struct

import numpy as np
import pytest

from d4rt.io.glb import FRUSTUM_COLOR, write_glb

COMPONENTS = {"VEC3": 3, "VEC4": 4}
DTYPES = {5126: "<f4", 5121: "u1"}


def read_glb(path):
    """-> (gltf JSON, {mesh name: (mode, {attribute: array})})."""
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_length, kind = struct.unpack_from("<I4s", data, 12)
    assert kind == b"JSON" and json_length % 4 == 0
    gltf = json.loads(data[20:20 + json_length])
    binary = b""
    if 20 + json_length < len(data):
        bin_length, kind = struct.unpack_from("<I4s", data, 20 + json_length)
        assert kind == b"BIN\x00" and bin_length % 4 == 0 and 28 + json_length + bin_length == len(data)
        binary = data[28 + json_length:]
        assert gltf["buffers"][0]["byteLength"] <= bin_length
    meshes = {}
    for mesh in gltf.get("meshes", []):
        (primitive,) = mesh["primitives"]
        arrays = {}
        for attribute, index in primitive["attributes"].items():
            accessor = gltf["accessors"][index]
            view = gltf["bufferViews"][accessor["bufferView"]]
            assert view["byteOffset"] % 4 == 0
            array = np.frombuffer(binary, DTYPES[accessor["componentType"]], offset=view["byteOffset"],
                                  count=accessor["count"] * COMPONENTS[accessor["type"]])
            arrays[attribute] = array.reshape(accessor["count"], -1)
            if attribute == "POSITION":  # required by the specification
                np.testing.assert_array_equal(accessor["min"], arrays[attribute].min(0))
                np.testing.assert_array_equal(accessor["max"], arrays[attribute].max(0))
        meshes[mesh["name"]] = primitive["mode"], arrays
    assert all(value != [] for value in gltf.values())  # the specification's minItems: 1
    names = [gltf["nodes"][i]["name"] for i in gltf["scenes"][gltf["scene"]].get("nodes", [])]
    assert names == [m["name"] for m in gltf.get("meshes", [])]
    return gltf, meshes


@pytest.mark.parametrize("num_points, num_frames", [(1001, 3), (0, 2), (7, 0), (0, 0)])
def test_glb_holds_the_points_and_frusta_in_gltf_axes(tmp_path, num_points, num_frames):
    rng = np.random.default_rng(num_points + num_frames)
    points = rng.normal(size=(num_points, 3)).astype(np.float32)
    colors = rng.integers(0, 256, (num_points, 3), dtype=np.uint8)
    frusta = rng.normal(size=(num_frames, 8, 2, 3))
    _, meshes = read_glb(write_glb(tmp_path / "scene.glb", points, colors, frusta))
    assert set(meshes) == {name for name, count in (("points", num_points), ("cameras", num_frames)) if count}
    if num_points:
        mode, arrays = meshes["points"]
        assert mode == 0  # POINTS
        np.testing.assert_array_equal(arrays["POSITION"], points * [1, -1, -1])  # OpenCV -> glTF (y up)
        np.testing.assert_array_equal(arrays["COLOR_0"], np.concatenate([colors, np.full((num_points, 1), 255)], 1))
    if num_frames:
        mode, arrays = meshes["cameras"]
        assert mode == 1  # LINES: each pair of vertices is one segment
        np.testing.assert_allclose(arrays["POSITION"], frusta.reshape(-1, 3) * [1, -1, -1], rtol=1e-6)
        assert (arrays["COLOR_0"] == FRUSTUM_COLOR).all()
