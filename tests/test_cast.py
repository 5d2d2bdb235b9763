"""``impress cast``: the digital cast is a closed, outward-oriented solid whose surface lies on
the heightmap, a raised letter F keeps its handedness (as recorded: an F seen from above; the
positive, turned over: the F as seen from below the impression, i.e. the outsole's face), the
base and the triangle cap hold, the same input gives the same bytes, and bad inputs give their
codes. Meshes are read back with open3d (not written here); the expected geometry comes from
the documented grid and export-frame conventions, not from the code under test."""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pytest

from impress_gui.cli import main
from impress_gui.core.base.errors import ImpressError, InputError
from impress_gui.core.measure import cast as C
from impress_gui.core.reconstruction.grid import GridSpec

o3d = pytest.importorskip("open3d")

PIXEL_MM = 0.25
SPEC = GridSpec(100.0, 40.0, PIXEL_MM, (260, 220))  # 55 x 65 mm
LETTER_MM = 2.0  # the F stands 2 mm above the ground
CENTRE = (127.0, -72.0)  # the letter's centre in the export frame, mm
HOLE = (slice(30, 45), slice(150, 170))  # a patch without data on the ground
TOL_AT_CELLS_MM = 1e-4  # surface vs heightmap at cell centres (float32 rounding)


def letter_f(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A letter F seen from above in a right-handed frame (x right, y up), 20 x 30 mm,
    centred at the origin: the stem on the left, the arms pointing right (+x)."""
    stem = (x >= -10) & (x <= -5) & (np.abs(y) <= 15)
    top = (x >= -10) & (x <= 10) & (y >= 10) & (y <= 15)
    mid = (x >= -10) & (x <= 5) & (np.abs(y) <= 2.5)
    return stem | top | mid


def ground(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 1.0 + 0.02 * (x - 100) - 0.01 * (y + 40) + 0.3 * np.sin(x / 7.0) * np.cos(y / 9.0)


def export_xy(spec: GridSpec, i, j):
    """docs/formats.md: cell [i, j] at rail (x0 + j p, y0 + i p); export x = rail X, y = -rail Y."""
    return spec.x0_mm + j * spec.pixel_mm, -(spec.y0_mm + i * spec.pixel_mm)


def synthetic_height(spec: GridSpec = SPEC) -> np.ndarray:
    ii, jj = np.mgrid[0 : spec.shape[0], 0 : spec.shape[1]]
    x, y = export_xy(spec, ii, jj)
    h = ground(x, y) + LETTER_MM * letter_f(x - CENTRE[0], y - CENTRE[1])
    h = h.astype(np.float32)
    h[HOLE] = np.nan
    h[:6, :] = np.nan  # rows and columns without data at the edges: not part of the cast
    h[:, -4:] = np.nan
    return h


def write_recon(folder, height: np.ndarray, spec: GridSpec = SPEC, record_hash: bool = True):
    """A reconstruction folder as impress process writes it (the parts cast reads)."""
    import tifffile

    folder.mkdir(parents=True, exist_ok=True)
    tifffile.imwrite(folder / "heightmap.tif", height.astype(np.float32))
    sha = hashlib.sha256((folder / "heightmap.tif").read_bytes()).hexdigest()
    meta = {"format": "impress.reconstruction", "version": 1, "software": "test",
            "grid": spec.to_json(),
            "inputs": {"video": {"sha256": "v" * 64}, "calibration": {"sha256": "c" * 64}}}
    if record_hash:
        meta["files"] = {"heightmap.tif": sha}
    (folder / "metadata.json").write_text(json.dumps(meta, indent=2))
    return folder


# ``cast_recon`` (conftest.py): a reconstruction folder of :func:`synthetic_height`


def read_mesh(path):
    mesh = o3d.io.read_triangle_mesh(str(path))
    mesh.remove_duplicated_vertices()  # STL stores three corners per triangle
    return mesh


def check_solid(mesh, full: bool = True) -> float:
    """Closed, 2-manifold, oriented, outward; ``full``: open3d's watertightness (with its
    self-intersection test, quadratic in time: small meshes only) and volume."""
    assert len(mesh.triangles) > 0
    assert mesh.is_edge_manifold(allow_boundary_edges=False)
    assert mesh.is_vertex_manifold()
    assert mesh.is_orientable()
    v = np.asarray(mesh.vertices)[np.asarray(mesh.triangles)]
    volume = float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6)
    if full:
        assert mesh.is_watertight()
        assert not mesh.is_self_intersecting()
        assert mesh.get_volume() == pytest.approx(volume, rel=1e-9)
    assert volume > 0  # outward normals
    return volume


def raycast_heights(mesh, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The mesh's top surface at (x, y): the first hit of a ray cast straight down."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    z0 = float(np.asarray(mesh.vertices)[:, 2].max()) + 1.0  # near: float32 precision
    rays = np.zeros((x.size, 6), np.float32)
    rays[:, 0], rays[:, 1], rays[:, 2], rays[:, 5] = x.ravel(), y.ravel(), z0, -1.0
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
    return (z0 - t).reshape(x.shape)


# ----- the solid ---------------------------------------------------------------------------
@pytest.mark.parametrize("positive", [False, True])
@pytest.mark.parametrize("suffix", [".stl", ".ply", ".obj"])
def test_watertight_outward_solid_in_every_format(cast_recon, tmp_path, positive, suffix):
    out = tmp_path / f"cast{suffix}"
    doc = C.write_cast(cast_recon, out, C.CastParams(decimate="sample", positive=positive, max_triangles=20000))
    mesh = read_mesh(out)
    volume = check_solid(mesh)
    assert len(mesh.triangles) == doc["mesh"]["triangles"] <= 20000
    assert len(mesh.vertices) == doc["mesh"]["vertices"]
    assert volume == pytest.approx(doc["mesh"]["volume_mm3"], rel=1e-5)
    if suffix == ".stl":  # the stored normals point out of the solid, as the winding says
        mesh.compute_triangle_normals()
        raw = np.frombuffer(out.read_bytes()[84:], dtype=[("n", "<f4", (3,)),
                                                          ("v", "<f4", (3, 3)), ("a", "<u2")])
        v = raw["v"].astype(np.float64)
        cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        assert np.all(np.einsum("ij,ij->i", cross, raw["n"]) >= 0)
        assert np.allclose(np.linalg.norm(raw["n"], axis=1), 1, atol=1e-5)


def test_full_resolution_surface_lies_on_the_heightmap(cast_recon, tmp_path):
    height = synthetic_height()
    for positive in (False, True):
        out = tmp_path / f"full{positive}.stl"
        doc = C.write_cast(cast_recon, out, C.CastParams(decimate="sample", positive=positive))
        assert doc["mesh"]["step_cells"] == 1
        mesh = read_mesh(out)
        check_solid(mesh, full=False)
        rng = np.random.default_rng(1)
        inner = np.isfinite(height)
        inner[[6, -1], :] = inner[:, [0, -5]] = False  # rays along the region's edge may miss
        ok = np.argwhere(inner)
        ii, jj = ok[rng.choice(len(ok), 2000, replace=False)].T
        x, y = export_xy(SPEC, ii, jj)
        h = height[ii, jj].astype(np.float64)
        if positive:  # turned over: (x, y, z) -> (-x, y, -z)
            x, h = -x, -h
        z = raycast_heights(mesh, x, y)
        assert np.max(np.abs(z - h)) <= TOL_AT_CELLS_MM
        # halfway between cells the surface is the mean of its neighbours (bilinear on a plane)
        verts = np.asarray(mesh.vertices)
        top = verts[:, 2] > verts[:, 2].min() + 1e-3
        assert top.sum() == doc["mesh"]["surface_vertices"][0] * doc["mesh"]["surface_vertices"][1]


def test_decimated_surface_keeps_heightmap_values_at_its_vertices(cast_recon, tmp_path):
    height = synthetic_height()
    out = tmp_path / "small.ply"
    doc = C.write_cast(cast_recon, out, C.CastParams(decimate="sample", max_triangles=30000))
    step = doc["mesh"]["step_cells"]
    assert step > 1
    r0, r1 = doc["region"]["rows"]
    c0, c1 = doc["region"]["cols"]
    rows = sorted(set(range(r0, r1, step)) | {r1 - 1})
    cols = sorted(set(range(c0, c1, step)) | {c1 - 1})
    ii, jj = np.meshgrid(rows[1:-1], cols[1:-1], indexing="ij")  # rays on the edge may miss
    ok = np.isfinite(height[ii, jj])
    x, y = export_xy(SPEC, ii[ok], jj[ok])
    mesh = read_mesh(out)
    z = raycast_heights(mesh, x, y)
    assert np.max(np.abs(z - height[ii, jj][ok])) <= TOL_AT_CELLS_MM
    # the whole ground away from the letter's edges stays within 0.05 mm of the map
    iy, jx = np.mgrid[r0 + 1 : r1 - 1 : 3, c0 + 1 : c1 - 1 : 3]
    x, y = export_xy(SPEC, iy, jx)
    d = np.arange(-1.5, 1.51, 0.25)
    near = [letter_f(x - CENTRE[0] + dx, y - CENTRE[1] + dy) for dx in d for dy in d]
    edge = np.any(near, axis=0) & ~np.all(near, axis=0)  # within 1.5 mm of the letter's walls
    sel = np.isfinite(height[iy, jx]) & ~edge
    z = raycast_heights(mesh, x[sel], y[sel])
    assert np.max(np.abs(z - height[iy, jx][sel])) <= 0.05


def test_region_holes_and_base(cast_recon, tmp_path):
    height = synthetic_height()
    out = tmp_path / "c.stl"
    doc = C.write_cast(cast_recon, out, C.CastParams(decimate="sample", base_mm=3.5))
    # default region: the bounding box of the cells with data (rows 6.., cols ..-4)
    assert doc["region"]["rows"] == [6, SPEC.shape[0]]
    assert doc["region"]["cols"] == [0, SPEC.shape[1] - 4]
    n_hole = (HOLE[0].stop - HOLE[0].start) * (HOLE[1].stop - HOLE[1].start)
    assert doc["holes"]["filled_cells"] == n_hole
    verts = np.asarray(read_mesh(out).vertices)
    region = height[6:, :-4]
    lo = float(np.nanmin(region))
    assert verts[:, 2].min() == pytest.approx(lo - 3.5, abs=1e-4)
    bottom = verts[np.abs(verts[:, 2] - verts[:, 2].min()) < 1e-6]
    assert len(bottom) == 2 * (region.shape[0] - 1 + region.shape[1] - 1) + 1  # flat base
    box = doc["mesh"]["bounding_box"]
    x0, y1 = export_xy(SPEC, 6, 0)
    x1, y0 = export_xy(SPEC, SPEC.shape[0] - 1, SPEC.shape[1] - 5)
    assert box["min_mm"] == pytest.approx([x0, y0, lo - 3.5], abs=1e-4)
    assert box["max_mm"] == pytest.approx([x1, y1, float(np.nanmax(region))], abs=1e-4)
    # the hole is filled smoothly: within the heights around it
    mesh = read_mesh(out)
    ii, jj = np.mgrid[HOLE[0], HOLE[1]]
    x, y = export_xy(SPEC, ii, jj)
    z = raycast_heights(mesh, x, y)
    ring = height[HOLE[0].start - 2 : HOLE[0].stop + 2, HOLE[1].start - 2 : HOLE[1].stop + 2]
    assert np.nanmin(ring) - 1e-3 <= z.min() and z.max() <= np.nanmax(ring) + 1e-3
    assert np.max(np.abs(z - ground(x, y))) < 0.15  # the smooth ground continues
    # the positive: base below the lowest point of the turned-over surface
    doc = C.write_cast(cast_recon, tmp_path / "p.stl", C.CastParams(decimate="sample", positive=True, base_mm=3.5))
    assert doc["mesh"]["base_z_mm"] == pytest.approx(-float(np.nanmax(region)) - 3.5, abs=1e-4)


def test_crop_in_the_export_frame(cast_recon, tmp_path):
    x0, y0, x1, y1 = 110.0, -90.0, 140.2, -60.0
    doc = C.write_cast(cast_recon, tmp_path / "c.stl", C.CastParams(decimate="sample", crop_mm=(x1, y1, x0, y0)))
    box = doc["mesh"]["bounding_box"]
    assert box["min_mm"][:2] == pytest.approx([110.0, -90.0])
    assert box["max_mm"][:2] == pytest.approx([140.0, -60.0])  # cell centres inside the crop
    assert doc["parameters"]["crop_mm"] == [x1, y1, x0, y0]
    assert doc["holes"]["filled_cells"] == 0


@pytest.mark.parametrize("far", [1e9, 1e12])
def test_a_crop_far_beyond_the_grid_on_one_axis_keeps_the_other(cast_recon, tmp_path, far):
    """A hostile-input audit: ``--crop=-1e12,0,1e12,10`` cast the whole grid's y range (the
    rounding allowance grew with the values); now x is the whole grid and y the 10 mm asked."""
    y0, y1 = -90.0, -60.0
    doc = C.write_cast(cast_recon, tmp_path / "c.stl",
                       C.CastParams(decimate="sample", crop_mm=(-far, y0, far, y1)))
    box = doc["mesh"]["bounding_box"]
    assert box["min_mm"][1] == pytest.approx(y0) and box["max_mm"][1] == pytest.approx(y1)
    assert doc["parameters"]["crop_mm"] == [-far, y0, far, y1]


@pytest.mark.parametrize("cap", [20, 1000, 12345, 100000])
def test_triangle_cap(cast_recon, tmp_path, cap):
    doc = C.write_cast(cast_recon, tmp_path / "c.stl", C.CastParams(decimate="sample", max_triangles=cap))
    n = doc["mesh"]["triangles"]
    assert n <= cap
    rows, cols = doc["region"]["cells"]
    step = doc["mesh"]["step_cells"]
    if step > 1:  # the finest sampling that fits
        nr = len(range(0, rows, step - 1)) + ((rows - 1) % (step - 1) != 0)
        nc = len(range(0, cols, step - 1)) + ((cols - 1) % (step - 1) != 0)
        assert 2 * (nr - 1) * (nc - 1) + 6 * (nr + nc - 2) > cap
    check_solid(read_mesh(tmp_path / "c.stl"), full=n < 20000)


# ----- handedness ----------------------------------------------------------------------------
def _relief_mask(mesh, raster_mm: float = 0.5) -> np.ndarray:
    """Where the surface departs from its median level by more than half the letter's height,
    on a raster of the mesh's own xy (x right, y up: row 0 = the largest y)."""
    v = np.asarray(mesh.vertices)
    lo, hi = v[:, :2].min(axis=0), v[:, :2].max(axis=0)
    xs = np.arange(lo[0] + 0.3, hi[0] - 0.3, raster_mm)
    ys = np.arange(hi[1] - 0.3, lo[1] + 0.3, -raster_mm)
    x, y = np.meshgrid(xs, ys)
    z = raycast_heights(mesh, x, y)
    return np.abs(z - np.median(z)) > LETTER_MM / 2


def _best_iou(mask: np.ndarray, letter: np.ndarray) -> tuple[float, int]:
    """Best overlap of ``mask`` with ``letter`` rotated by 0, 90, 180 or 270 degrees (in the
    plane: no mirror), centroids aligned."""
    best = (0.0, -1)
    pts = np.argwhere(mask)
    for k in range(4):
        ref = np.argwhere(np.rot90(letter, k))
        shift = np.round(pts.mean(axis=0) - ref.mean(axis=0)).astype(int)
        a = {tuple(p) for p in pts}
        b = {tuple(p) for p in ref + shift}
        iou = len(a & b) / len(a | b)
        best = max(best, (iou, k))
    return best


@pytest.mark.parametrize("positive", [False, True])
def test_a_raised_letter_keeps_its_handedness(cast_recon, tmp_path, positive):
    out = tmp_path / "f.stl"
    C.write_cast(cast_recon, out, C.CastParams(decimate="sample", positive=positive, max_triangles=400000))
    mask = _relief_mask(read_mesh(out))
    s = np.arange(-16, 16.01, 0.5)
    x, y = np.meshgrid(s, s[::-1])  # row 0 = the largest y, as the mask
    f = letter_f(x, y)
    mirrored = letter_f(-x, y)
    iou_f, rot_f = _best_iou(mask, f)
    iou_m, rot_m = _best_iou(mask, mirrored)
    if not positive:  # as recorded, seen from above: an F, upright
        assert iou_f > 0.85 and rot_f == 0 and iou_m < 0.7
    else:  # turned over about y: the F as seen from below (mirrored), still upright
        assert iou_m > 0.85 and rot_m == 0 and iou_f < 0.7


def test_positive_is_the_rotation_of_the_poured_cast(cast_recon, tmp_path):
    """Every surface vertex of the positive is the rotation by 180 deg about y of the same
    cell's vertex in the negative: (x, y, z) -> (-x, y, -z)."""
    neg = C.write_cast(cast_recon, tmp_path / "n.ply", C.CastParams(decimate="sample", max_triangles=50000))
    pos = C.write_cast(cast_recon, tmp_path / "p.ply", C.CastParams(decimate="sample", positive=True,
                                                               max_triangles=50000))
    vn = np.asarray(read_mesh(tmp_path / "n.ply").vertices)
    vp = np.asarray(read_mesh(tmp_path / "p.ply").vertices)
    nr, nc = neg["mesh"]["surface_vertices"]
    assert pos["mesh"]["surface_vertices"] == [nr, nc]
    top_n, top_p = vn[: nr * nc], vp[: nr * nc]
    assert np.allclose(top_p, top_n * [-1, 1, -1], atol=1e-5)
    assert pos["frame"]["matrix"] == [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]
    assert np.linalg.det(np.array(pos["frame"]["matrix"])[:3, :3]) == 1


# ----- provenance and reproducibility --------------------------------------------------------
def test_same_input_same_bytes_and_the_record(cast_recon, tmp_path):
    # nine casts: at most 10 000 triangles (8 800, every third cell) each is verified in under
    # a second; 50 000 left 19 000 (every second cell) and took 3-4 s each, nearly all of it
    # open3d's self-intersection test, which this test is not about
    params = C.CastParams(decimate="sample", positive=True, base_mm=4.0, max_triangles=10000,
                          crop_mm=(105.0, -100.0, 150.0, -50.0))
    for suffix in (".stl", ".ply", ".obj"):
        a, b = tmp_path / f"a{suffix}", tmp_path / "again" / f"a{suffix}"
        C.write_cast(cast_recon, a, params)
        C.write_cast(cast_recon, b, params)
        assert a.read_bytes() == b.read_bytes()
        assert (tmp_path / f"a{suffix}.json").read_bytes() == \
            (tmp_path / "again" / f"a{suffix}.json").read_bytes()
        C.write_cast(cast_recon, a, params)  # replacing its own output
    data = (tmp_path / "a.stl").read_bytes()
    doc = C.read_cast_document(tmp_path / "a.stl.json")
    meta_sha = hashlib.sha256((cast_recon / "metadata.json").read_bytes()).hexdigest()
    tif_sha = hashlib.sha256((cast_recon / "heightmap.tif").read_bytes()).hexdigest()
    src = doc["inputs"]["reconstruction"]
    assert src["metadata_json_sha256"] == meta_sha and src["heightmap_tif_sha256"] == tif_sha
    assert doc["mesh"]["sha256"] == hashlib.sha256(data).hexdigest()
    assert doc["mesh"]["bytes"] == len(data) and doc["mesh"]["file"] == "a.stl"
    assert doc["parameters"] == {"mode": "positive", "base_mm": 4.0,
                                 "crop_mm": [105.0, -100.0, 150.0, -50.0],
                                 "max_triangles": 10000, "decimate": "sample"}
    assert doc["frame"]["handedness"] == "right" and "180 deg about the y axis" in \
        doc["frame"]["transformation"]
    header = data[:80].decode("ascii")
    assert not header.startswith("solid")
    assert header.startswith("IMPREsS") and " pos " in header and "b=4 " in header
    assert "t=10000" in header and "c=105,-100,150,-50" in header
    assert meta_sha[:12] in header
    assert int.from_bytes(data[80:84], "little") == doc["mesh"]["triangles"]
    ply_head = (tmp_path / "a.ply").read_bytes().split(b"end_header")[0].decode("ascii")
    assert meta_sha in ply_head and "parameters.base_mm: 4.0" in ply_head


def test_command_line(cast_recon, tmp_path, capsys):
    out = tmp_path / "shoe.stl"
    assert main(["cast", str(cast_recon), "-o", str(out), "--positive", "--base-mm", "2",
                 "--max-triangles", "40000", "--crop", "105,-100,150,-50"]) == 0
    text = capsys.readouterr().out
    assert "cast written to" in text and "positive" in text
    doc = json.loads((tmp_path / "shoe.stl.json").read_text())
    assert doc["parameters"]["base_mm"] == 2.0 and doc["mesh"]["triangles"] <= 40000
    check_solid(read_mesh(out), full=False)


# ----- bad inputs ------------------------------------------------------------------------------
def _fails(capsys, argv, code) -> None:
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's usage errors
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    assert f"[{code}]" in err and "Traceback" not in err


def test_bad_inputs_give_their_codes(cast_recon, tmp_path, capsys):
    out = str(tmp_path / "o.stl")
    _fails(capsys, ["cast", str(tmp_path / "nowhere"), "-o", out], "E-CAST-NO-RECON")
    _fails(capsys, ["cast", str(cast_recon / "heightmap.tif"), "-o", out], "E-CAST-NOT-FOLDER")
    (tmp_path / "empty").mkdir()
    _fails(capsys, ["cast", str(tmp_path / "empty"), "-o", out], "E-FILE-MISSING")
    nan = write_recon(tmp_path / "nan", np.full((20, 30), np.nan, np.float32),
                      GridSpec(0.0, 0.0, 0.5, (20, 30)))
    _fails(capsys, ["cast", str(nan), "-o", out], "E-CAST-NO-DATA")
    _fails(capsys, ["cast", str(cast_recon), "-o", out, "--base-mm", "-1"], "E-CAST-BASE")
    _fails(capsys, ["cast", str(cast_recon), "-o", out, "--base-mm", "0"], "E-CAST-BASE")
    _fails(capsys, ["cast", str(cast_recon), "-o", out, "--base-mm", "nan"], "E-USAGE")
    _fails(capsys, ["cast", str(cast_recon), "-o", out, "--max-triangles", "10"],
           "E-CAST-TRIANGLES")
    _fails(capsys, ["cast", str(cast_recon), "-o", out, "--crop", "0,0,5,5"], "E-CAST-CROP")
    _fails(capsys, ["cast", str(cast_recon), "-o", out, "--crop", "1,2,3"], "E-USAGE")
    _fails(capsys, ["cast", str(cast_recon), "-o", str(tmp_path / "o.step")], "E-CAST-SUFFIX")
    _fails(capsys, ["cast", str(cast_recon), "-o", str(cast_recon)], "E-OUTPUT-HOLDS-INPUT")
    _fails(capsys, ["cast", str(cast_recon), "-o", str(cast_recon / "cast.stl")],
           "E-OUTPUT-HOLDS-INPUT")
    _fails(capsys, ["cast", str(cast_recon), "-o", str(cast_recon / "heightmap.tif")],
           "E-OUTPUT-HOLDS-INPUT")
    (tmp_path / "dir.stl").mkdir()
    _fails(capsys, ["cast", str(cast_recon), "-o", str(tmp_path / "dir.stl")], "E-OUTPUT-NOT-FILE")
    (tmp_path / "other.stl.json").write_text('{"format": "someone.else"}')
    _fails(capsys, ["cast", str(cast_recon), "-o", str(tmp_path / "other.stl")], "E-OUTPUT-EXISTS")
    # a file of a mesh's name that no cast wrote (another folder's point cloud, a video
    # renamed): not replaced (a hostile-input audit found both replaced)
    foreign = tmp_path / "cloud.ply"
    foreign.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    _fails(capsys, ["cast", str(cast_recon), "-o", str(foreign)], "E-OUTPUT-EXISTS")
    assert foreign.read_bytes().startswith(b"ply\nformat ascii")
    assert not (tmp_path / "cloud.ply.json").exists()
    assert not (tmp_path / "o.stl").exists() and not (tmp_path / "other.stl").exists()
    assert sorted(p.name for p in cast_recon.iterdir()) == ["heightmap.tif", "metadata.json"]
    # a heightmap changed after processing
    bad = write_recon(tmp_path / "changed", synthetic_height())
    h = synthetic_height()
    h[100, 100] += 1
    import tifffile

    tifffile.imwrite(bad / "heightmap.tif", h)
    _fails(capsys, ["cast", str(bad), "-o", out], "E-CAST-HASH")
    # a crop holding only cells without data
    _fails(capsys, ["cast", str(cast_recon), "-o", out, "--crop", "138,-48,142,-50.9"],
           "E-CAST-NO-DATA")


@pytest.mark.parametrize("bad", [math.nan, -1.0, 0.0, math.inf, 2000.0])
def test_core_refuses_bad_bases(bad):
    with pytest.raises(InputError) as info:
        C.make_cast(synthetic_height(), SPEC, C.CastParams(decimate="sample", base_mm=bad))
    assert info.value.code == "E-CAST-BASE"


def test_fill_is_exact_on_known_cells_and_smooth():
    rng = np.random.default_rng(3)
    ii, jj = np.mgrid[0:90, 0:130]
    plane = 0.01 * ii - 0.02 * jj + 3
    h = plane.copy()
    h[rng.random(h.shape) < 0.3] = np.nan
    h[20:50, 40:90] = np.nan
    out = C.fill_holes(h)
    known = np.isfinite(h)
    assert np.array_equal(out[known], h[known])
    assert np.max(np.abs(out - plane)) < 0.05  # a plane is harmonic: the fill follows it
    with pytest.raises(ImpressError):
        C.fill_holes(np.full((3, 3), np.nan))


# ----- a real reconstruction: the simulator's raised letter F ----------------------------------
# (``letter_scan``: the scan and its reconstruction, made once a run by conftest.py)


def _raster(x: np.ndarray, y: np.ndarray, raster_mm: float = 0.5) -> np.ndarray:
    """Points (export frame) as a mask, row 0 = the largest y (seen from above)."""
    cols = np.round((x - x.min()) / raster_mm).astype(int)
    rows = np.round((y.max() - y) / raster_mm).astype(int)
    m = np.zeros((rows.max() + 1, cols.max() + 1), bool)
    m[rows, cols] = True
    return m


@pytest.mark.slow
@pytest.mark.parametrize("positive", [False, True])
def test_simulated_letter_cast(letter_scan, tmp_path, positive):
    """A reconstruction of the simulator's raised F: the cast is a closed outward solid, its
    surface passes through the heightmap, and the letter (the simulator's truth, not a letter
    drawn here) keeps its handedness under rotation only."""
    import tifffile

    from impress_gui.sim.truth import truth_on_grid

    scan, cast_recon = letter_scan
    g = json.loads((cast_recon / "metadata.json").read_text())["grid"]
    spec = GridSpec(g["x0_mm"], g["y0_mm"], g["pixel_mm"], tuple(g["shape"]))
    height = tifffile.imread(cast_recon / "heightmap.tif")
    truth = truth_on_grid(scan, spec)
    ii, jj = np.nonzero((truth > 3.0) & (truth < 8.5))  # the 6 mm letter, not the target
    lx, ly = export_xy(spec, ii, jj)
    crop = (lx.min() - 8, ly.min() - 8, lx.max() + 8, ly.max() + 8)
    out = tmp_path / "letter.stl"
    doc = C.write_cast(cast_recon, out, C.CastParams(decimate="sample", positive=positive, crop_mm=crop))
    assert doc["mesh"]["step_cells"] == 1
    mesh = read_mesh(out)
    check_solid(mesh, full=doc["mesh"]["triangles"] < 40000)
    # the surface passes through every cell with data (inside the region's edge)
    r0, r1 = doc["region"]["rows"]
    c0, c1 = doc["region"]["cols"]
    ri, cj = np.mgrid[r0 + 1 : r1 - 1, c0 + 1 : c1 - 1]
    ok = np.isfinite(height[ri, cj])
    x, y = export_xy(spec, ri[ok], cj[ok])
    h = height[ri, cj][ok].astype(np.float64)
    s = -1.0 if positive else 1.0
    assert np.max(np.abs(raycast_heights(mesh, s * x, y) - s * h)) <= TOL_AT_CELLS_MM
    # handedness: as recorded the truth's F; the positive the F seen from below
    v = np.asarray(mesh.vertices)
    lo, hi = v[:, :2].min(axis=0), v[:, :2].max(axis=0)
    gx, gy = np.meshgrid(np.arange(lo[0] + 0.3, hi[0] - 0.3, 0.5),
                         np.arange(hi[1] - 0.3, lo[1] + 0.3, -0.5))
    z = raycast_heights(mesh, gx, gy)
    mask = np.abs(z - np.median(z)) > 3.0
    expected, wrong = _raster(s * lx, ly), _raster(-s * lx, ly)
    iou, rot = _best_iou(mask, expected)
    iou_wrong, _ = _best_iou(mask, wrong)
    assert iou > 0.75 and rot == 0 and iou_wrong < 0.6, (iou, rot, iou_wrong)


def test_progress_and_cancel(cast_recon, tmp_path):
    from impress_gui.core.base.errors import Cancelled
    from impress_gui.core.base.progress import CancelToken

    seen: list[float] = []
    C.write_cast(cast_recon, tmp_path / "a.stl", C.CastParams(decimate="sample", max_triangles=5000),
                 progress=lambda f, _msg: seen.append(f))
    assert seen[0] == 0.0 and seen[-1] == 1.0 and seen == sorted(seen)
    token = CancelToken()
    token.cancel()
    with pytest.raises(Cancelled):
        C.write_cast(cast_recon, tmp_path / "b.stl", C.CastParams(decimate="sample"), cancel=token)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.stl", "a.stl.json"]
