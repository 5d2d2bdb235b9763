"""The cast's mesh checks and its printed summary (issue 20).

``verify_mesh`` takes edge-manifoldness and orientability from numpy's edge check (every
directed edge once and its reverse once, no triangle naming a vertex twice) and asks open3d
only when that check fails: the recorded values must be open3d's own (``is_edge_manifold``
without boundary edges, ``is_orientable``) on the test casts (sampled, quadric, full
resolution, positive) and on deliberately broken meshes (a flipped triangle, a removed
triangle, a degenerate triangle), and the overall verdict that of all of open3d's tests.

``impress cast`` prints what the sidecar records; a record without vertical figures (every
vertical ray missed the mesh: ``normal`` but no ``tolerance_mm``, docs/formats.md) or without
any measured cell is said so, never a traceback after the files were written."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from test_cast import synthetic_height

from impress_gui.cli import main
from impress_gui.core.measure import cast as C
from impress_gui.core.measure.readings import load_reconstruction

o3d = pytest.importorskip("open3d")


def open3d_checks(mesh: C.CastMesh) -> dict:
    """What verify_mesh recorded before the numpy shortcut: open3d's tests, all of them."""
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices.astype(np.float64)),
                                  o3d.utility.Vector3iVector(mesh.triangles.astype(np.int32)))
    out = {"edge_manifold": bool(m.is_edge_manifold(allow_boundary_edges=False)),
           "vertex_manifold": bool(m.is_vertex_manifold()),
           "orientable": bool(m.is_orientable()),
           "closed_consistently_wound": C.closed_and_oriented(mesh.triangles),
           "volume_positive": bool(C.signed_volume(mesh.vertices, mesh.triangles) > 0)}
    ok = all(out.values())
    if len(mesh.triangles) <= C.SELF_INTERSECTION_MAX_TRIANGLES:
        ok = ok and not m.is_self_intersecting()
    return out | {"ok": ok}


def with_triangles(mesh: C.CastMesh, tris: np.ndarray) -> C.CastMesh:
    return dataclasses.replace(mesh, triangles=np.ascontiguousarray(tris, np.int64))


def assert_same_verdicts(mesh: C.CastMesh) -> dict:
    got, want = C.verify_mesh(mesh), open3d_checks(mesh)
    assert {k: got[k] for k in want} == want
    return got


@pytest.fixture(scope="module")
def height_and_spec(cast_recon):
    data = load_reconstruction(cast_recon, layers=("fused",))
    return data.height_mm, data.spec


@pytest.mark.parametrize("params", [
    C.CastParams(decimate="sample"),  # full resolution, 111,598 triangles
    C.CastParams(decimate="sample", max_triangles=30000),
    C.CastParams(decimate="sample", max_triangles=5000, positive=True),
    C.CastParams(max_triangles=30000, decimate="quadric"),
    C.CastParams(max_triangles=5000, decimate="quadric", positive=True),
], ids=["full", "sample-30k", "sample-5k-positive", "quadric-30k", "quadric-5k-positive"])
def test_numpy_edge_check_gives_open3d_verdicts_on_the_casts(height_and_spec, params):
    mesh = C.make_cast(*height_and_spec, params)
    got = assert_same_verdicts(mesh)
    assert got["ok"] and got["edge_manifold"] and got["orientable"]


@pytest.mark.parametrize("decimate", ["sample", "quadric"])
def test_numpy_edge_check_gives_open3d_verdicts_on_broken_meshes(height_and_spec, decimate):
    mesh = C.make_cast(*height_and_spec, C.CastParams(max_triangles=5000, decimate=decimate))
    t = mesh.triangles
    k = len(t) // 3  # a triangle of the top surface
    flipped = t.copy()
    flipped[k] = flipped[k, [0, 2, 1]]
    got = assert_same_verdicts(with_triangles(mesh, flipped))
    # still a closed 2-manifold that could be oriented, but not wound consistently
    assert got["edge_manifold"] and got["orientable"]
    assert not got["closed_consistently_wound"] and not got["ok"]

    got = assert_same_verdicts(with_triangles(mesh, np.delete(t, k, axis=0)))  # a hole
    assert not got["edge_manifold"] and not got["closed_consistently_wound"]
    assert not got["ok"]

    a, b = t[k, 0], t[k, 1]  # a triangle naming a vertex twice, on an existing edge
    got = assert_same_verdicts(with_triangles(mesh, np.vstack([t, [[a, a, b]]])))
    assert not got["edge_manifold"] and not got["ok"]

    # a second shell wound inside out: every edge still has two triangles wound opposite
    # ways, so only the volume's sign catches it (open3d calls it orientable too)
    n = len(mesh.vertices)
    two = dataclasses.replace(mesh, vertices=np.vstack([mesh.vertices,
                                                        2 * mesh.vertices + 1000.0]))
    inside_out = np.vstack([t, t[:, [0, 2, 1]] + n])
    got = assert_same_verdicts(with_triangles(two, inside_out))
    assert not got["ok"]


def test_open3d_runs_only_when_the_edge_check_fails(height_and_spec, monkeypatch):
    """The speed-up: a closed, consistently wound cast never reaches open3d's edge-manifold
    and orientability tests (about 27 s on a 1.7-million-triangle cast)."""
    mesh = C.make_cast(*height_and_spec, C.CastParams(decimate="sample", max_triangles=30000))
    calls = []
    real = o3d.geometry.TriangleMesh

    class Spy(real):
        def is_orientable(self):
            calls.append("orientable")
            return super().is_orientable()

        def is_edge_manifold(self, allow_boundary_edges=True):
            calls.append("edge_manifold")
            return super().is_edge_manifold(allow_boundary_edges)

    monkeypatch.setattr(o3d.geometry, "TriangleMesh", Spy)
    assert C.verify_mesh(mesh)["ok"] and calls == []
    flipped = mesh.triangles.copy()
    flipped[0] = flipped[0, [0, 2, 1]]
    assert not C.verify_mesh(with_triangles(mesh, flipped))["ok"]
    assert calls == ["edge_manifold", "orientable"]


# ----- the printed summary -------------------------------------------------------------------
class MissingRays:
    """open3d's RaycastingScene whose vertical rays all miss (t_hit infinite); the distances
    along the normal are open3d's own."""

    def __init__(self):
        self._scene = _REAL_SCENE()

    def __getattr__(self, name):
        return getattr(self._scene, name)

    def cast_rays(self, rays):
        out = self._scene.cast_rays(rays)
        t = np.full(out["t_hit"].shape, np.inf, np.float32)
        return {"t_hit": o3d.core.Tensor(t), "primitive_ids": out["primitive_ids"]}


_REAL_SCENE = o3d.t.geometry.RaycastingScene


def test_every_vertical_ray_missed(cast_recon, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(o3d.t.geometry, "RaycastingScene", MissingRays)
    out = tmp_path / "cast.stl"
    assert main(["cast", str(cast_recon), "-o", str(out), "--max-triangles", "5000"]) == 0
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and "error" not in captured.err
    dev = json.loads((tmp_path / "cast.stl.json").read_text())["surface_deviation"]
    # the situation the record documents: normal and missed, no vertical figures
    assert "normal" in dev and dev["missed"] == dev["cells"] > 0
    assert "tolerance_mm" not in dev and "max_mm" not in dev
    text = captured.out
    assert f"all {dev['cells']} ray(s) missed the mesh; no vertical figures" in text
    assert "along the normal (closest point)" in text
    assert f"of {dev['cells']} cells within {C.SURFACE_TOLERANCE_MM:g} mm" in text
    assert "record: " in text


def test_summary_of_records_without_figures(cast_recon, tmp_path):
    from impress_gui.commands.cast import summary_lines

    out = tmp_path / "c.stl"
    doc = C.write_cast(cast_recon, out, C.CastParams(decimate="sample", max_triangles=5000))
    full = summary_lines(doc, out)
    dev = doc["surface_deviation"]
    assert any("(vertical)" in line for line in full)
    assert any(f"of {dev['cells']} cells within 0.02 mm" in line for line in full)

    missed = dict(doc, surface_deviation={
        k: v for k, v in dev.items() if k in ("method", "stride_cells", "cells", "normal")
    } | {"missed": dev["cells"]})
    lines = summary_lines(missed, out)
    assert any("missed the mesh; no vertical figures" in line for line in lines)
    assert any("along the normal" in line and "within 0.02 mm" in line for line in lines)

    none = dict(doc, surface_deviation={"method": dev["method"], "stride_cells": 1,
                                        "cells": 0, "missed": 0})
    lines = summary_lines(none, out)
    assert any("no cell with data was measured" in line for line in lines)
    assert not any("along the normal" in line for line in lines)


def test_vertical_method_says_what_is_measured(cast_recon, tmp_path):
    """The vertical figures are unsigned (absolute differences), as the method says."""
    doc = C.write_cast(cast_recon, tmp_path / "c.stl", C.CastParams(decimate="sample", max_triangles=5000))
    method = doc["surface_deviation"]["method"]
    assert "absolute difference" in method and "minus" not in method
    assert synthetic_height().shape == tuple(doc["grid"]["shape"])
