"""Method validation (issue 8): the thesis' protocol end to end in quick mode on the "Order AB"
placement and the flat plane, the protocol's own geometry against the simulator's truth, the
plane and sphere quantities on exact surfaces, the real-scan spec path, the table, the report,
the command and the dialog.

Tolerances in quick mode (640x360, 78.8 mm/s here: one camera pixel is 0.38 mm on the
targets, 2.6 mm of travel per frame):
- z (slot depths, step rises): every reading within 0.15 mm, mean <= 0.19 mm (the issue's bar:
  five times better than the thesis' 0.94 mm);
- xy (slot and tread widths): mean <= 0.35 mm. The bar (0.12 mm) needs the full mode: at
  640x360 the reconstruction loses about one camera column of the upper surface at each
  edge (see docs/validation.md), which widens slots by ~0.2-0.5 mm;
- flatness (0.3 % trimmed range of the residuals) <= 0.6 mm, RMS <= 0.1 mm, plane height
  within 0.15 mm of the truth.
The stated uncertainties (issue 22): every reading's U (about 95 %) and the share of each kind's
readings whose true error lies within it, in the record, the table and the report.
The rendered scans are kept in pytest's cache folder between sessions (keyed by the
simulator's code and the scan's settings); a cold run renders them first (about a minute).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import truth_on_grid

from impress_gui import __version__
from impress_gui.core.base.errors import Cancelled, FormatError, InputError
from impress_gui.core.base.fileio import sha256_file, write_json
from impress_gui.core.base.progress import CancelToken
from impress_gui.core.calibration import uncertainty as CU
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.validation import protocol as V
from impress_gui.validation import vdi as VDI
from impress_gui.validation.report import format_table, report_html, write_report
from impress_gui.validation.run import RunConfig, run_real, run_simulated
from impress_gui.validation.spec import load_spec

#: one rendering process: with two, each builds the scene again (8.5 s for AB, 3 s for the
#: plane) and the test suite's other worker already has the second core (the frames are the
#: same, and a scan made either way is reused). 10 Monte Carlo trials behind the readings'
#: uncertainties, not the product's 60: the run's slowest part (tests/test_uncertainty.py
#: checks the Monte Carlo itself); the record states the number. The calibration is a small
#: part of these readings' U: measured 7 December 2026, 10 trials against 20 moved no U by
#: more than 0.005 mm and no reading's coverage (edge distances 12/12, steps 9/12 with
#: either; 11 s less)
QUICK = dict(speed_mm_s=78.828, placements=("AB",), extras=("flat",), workers=1,
             uncertainty_trials=10)


@pytest.fixture(scope="module")
def run(request, tmp_path_factory):
    out = tmp_path_factory.mktemp("validation")
    scans = request.config.cache.mkdir("impress-validation-scans")
    seen = []
    record = run_simulated(
        RunConfig.quick(**QUICK), out, lambda f, m: seen.append((f, m)), scans_dir=scans
    )
    paths = write_report(record, out)
    return {"out": out, "scans": scans, "record": record, "paths": paths, "progress": seen}


def test_quick_mode_meets_the_z_bar_and_its_xy_tolerance(run):
    rec = run["record"]
    readings = rec["readings"]
    assert len(readings) == 2 * 4 * len(V.STATIONS_MM)  # two targets, four dimensions each
    assert all(r["error_mm"] is not None for r in readings), [
        r for r in readings if r["error_mm"] is None
    ]
    z = [abs(r["error_mm"]) for r in readings if r["axis"] == "z"]
    xy = [abs(r["error_mm"]) for r in readings if r["axis"] == "xy"]
    assert len(z) == len(xy) == 12
    assert max(z) < 0.15 and np.mean(z) <= V.BAR_Z_MM
    assert np.mean(xy) <= 0.35
    ov = rec["summary"]["Overall"]
    assert ov["z"]["mean_abs_mm"] == pytest.approx(np.mean(z), abs=1e-4)
    assert ov["xy"]["sd_mm"] == pytest.approx(np.std(xy, ddof=1), abs=1e-4)
    assert rec["acceptance"]["z_ok"] and not rec["acceptance"]["all_placements"]
    f = rec["flat"]
    assert f["flatness_mm"] <= 0.6 and f["rms_mm"] <= 0.1 and abs(f["offset_mm"]) <= 0.15
    assert f["n"] > 300_000
    # progress rose to the end
    fr = [p[0] for p in run["progress"]]
    assert fr[-1] == pytest.approx(1.0) and all(b >= a - 1e-9 for a, b in zip(fr, fr[1:]))


#: the least share of a kind's readings whose true error must lie within their U (about 95 %) in the
#: quick run. Measured 25 November 2026 with the per-laser maps: edge distance 12/12, step 12/12
#: (the steps closest to their U: errors of 0.104 and 0.051 mm against 0.119 and 0.056 mm); with
#: the first (uncapped) window sub-pixel estimate as the default, step 10/12 (0.088 against
#: 0.085, 0.061 against 0.059 mm), so up to three misses per kind are tolerated (the capped
#: window, the default since, passes it). A floor, not the target (about 95 %): 12 readings
#: sharing one calibration give a coarse figure; the CLI's quick run over all six placements
#: covered only 48/72 steps (docs/validation.md: steps under-stated, issue 22).
COVERAGE_FLOOR = 0.75


def test_the_record_and_table_state_the_uncertainty_coverage(run):
    """issue 22: every reading carries its U (about 95 %) and k and whether it covers the true error; the
    record counts them per kind, the table, the report and the saved record say so."""
    rec = run["record"]
    assert rec["config"]["uncertainty_trials"] == QUICK["uncertainty_trials"] == 10
    assert RunConfig().uncertainty_trials == CU.DEFAULT_TRIALS  # the product's own default
    readings, cov = rec["readings"], rec["uncertainty_coverage"]
    kinds = sorted({r["kind"] for r in readings})
    assert kinds == ["edge_distance", "step"]
    assert set(cov) == {*kinds, "all"}
    for r in readings:
        assert r["U_k2_mm"] is not None and r["U_k2_mm"] > 0, r
        # U = k u_c, k = 2 or less where a rectangular component (a wall in a gap) shapes
        # the sum (uncertainty.coverage_factor): never below one rectangle's alone
        assert 1.65 <= r["k"] <= 2.0, r
        assert r["U_k2_mm"] == pytest.approx(r["k"] * r["u_c_mm"], abs=2e-5)
        assert r["covered"] is (abs(r["error_mm"]) <= r["U_k2_mm"]), r
        if r["kind"] == "step":  # a step's U is of its bands' noise and the calibration
            assert 0.01 < r["U_k2_mm"] < 0.5, r
        else:  # an edge distance's U is mostly the lateral sampling (0.72-0.73 mm measured);
            # its calibration part once divided the height error by a near-flat slope (3-34 mm)
            assert 0.1 < r["U_k2_mm"] < 1.5, r
    for kind in [*kinds, "all"]:
        mine = [r for r in readings if kind in ("all", r["kind"])]
        c = cov[kind]
        assert c["n"] == len(mine) == (24 if kind == "all" else 12)
        assert c["covered"] == sum(r["covered"] is True for r in mine)
        assert 0.0 <= c["share"] <= 1.0
        assert c["share"] == pytest.approx(c["covered"] / c["n"], abs=1e-4)
        assert c["share"] >= COVERAGE_FLOOR, (kind, c)
    # the table (also in the HTML report) and the saved record state it
    line = next(x for x in run["paths"]["table"].read_text().splitlines()
                if x.startswith("Stated uncertainty (U, about 95 %) covers the true error:"))
    for kind in [*kinds, "all"]:
        c = cov[kind]
        assert (f"{kind.replace('_', ' ')} {c['covered']}/{c['n']} "
                f"({100 * c['share']:.1f} %)") in line
    assert line in run["paths"]["report"].read_text()
    saved = json.loads((run["out"] / "validation.json").read_text())
    assert saved["uncertainty_coverage"] == cov


def test_the_protocol_measures_the_truth_itself_exactly(run):
    """The readings' positions and bands come from the truth; on the true surface (resampled
    onto the reconstruction's grid) every reading is within the 0.1 mm grid's quantisation."""
    from impress_gui.core.measure.readings import load_reconstruction

    scan = run["scans"] / "AB"
    truth = json.loads((scan / "truth.json").read_text())
    rec = load_reconstruction(run["out"] / "runs" / "AB" / "reconstruction", layers=("fused",))
    true_h = truth_on_grid(scan, rec.spec)
    res = V.measure_all(true_h, rec.spec, V.blocks_readings(truth, "truth"))
    errs = np.array([r.error_mm for r in res])
    assert np.isfinite(errs).all() and np.abs(errs).max() <= 0.1, [
        (r.reading.id, r.error_mm) for r in res if not abs(r.error_mm) <= 0.1
    ]


def test_table_and_report_carry_versions_hashes_and_the_thesis(run):
    rec, paths = run["record"], run["paths"]
    table = paths["table"].read_text()
    assert table == format_table(rec)
    line = next(x for x in table.splitlines() if x.startswith("Order AB"))
    assert line.split()[-4:] == ["0.54", "0.34", "1.45", "0.47"]  # the thesis' row beside ours
    assert "0.60  0.39  0.94  0.51  (208 readings)" in table
    assert "Plane (VDI/VDE 2634-2 flatness)" in table
    html = paths["report"].read_text()
    assert f"impress {__version__}" in html and rec["date_utc"] in html
    scan = rec["scans"][0]
    video_sha = sha256_file(scan["inputs"]["video"]["path"])
    assert video_sha in html and scan["inputs"]["calibration"]["sha256"] in html
    assert scan["reconstruction"]["files"]["heightmap.tif"] in html
    assert "&quot;speed_mm_s&quot;: 78.828" in html  # the parameters
    assert "1.45" in html and "0.94" in html and "208 readings" in html
    imgs = re.findall(r"src='data:image/png;base64,[A-Za-z0-9+/=]+'", html)
    assert len(imgs) >= 2  # the chart and the measuring positions, inline
    assert "http://" not in html.replace("http://www.w3", "") and "src='http" not in html
    saved = json.loads((run["out"] / "validation.json").read_text())
    assert saved["format"] == "impress.validation" and saved["version"] == 1
    assert saved["software"] == f"impress {__version__}"


def test_a_real_scan_spec_gives_the_same_readings(run, tmp_path):
    """The simulator run writes its readings as a real-scan spec (a template for physical
    artefacts): measuring from it, without any truth, reproduces every value."""
    spec = run["out"] / "validation-spec.json"
    rec = run_real(spec, tmp_path)
    a = {r["id"]: r["measured_mm"] for r in run["record"]["readings"]}
    b = {r["id"]: r["measured_mm"] for r in rec["readings"]}
    assert a == b
    assert rec["kind"] == "real" and rec["spec"]["sha256"] == sha256_file(spec)
    html = report_html(rec, figures=False)
    assert rec["spec"]["sha256"] in html
    assert rec["scans"][0]["inputs"]["video"]["sha256"] in html


def test_the_command_prints_the_table(run, tmp_path, capsys):
    from impress_gui.cli import main

    code = main(
        [
            "validate",
            "--spec",
            str(run["out"] / "validation-spec.json"),
            "--out",
            str(tmp_path),
            "--no-figures",
        ]
    )
    out = capsys.readouterr().out
    assert code in (0, 1)  # 1: the quick scans do not meet the xy bar
    assert "Order AB" in out and "thesis table 4.1" in out and "Acceptance" in out
    assert (tmp_path / "validation_report.html").is_file()


def test_the_output_never_goes_into_a_reconstruction_the_spec_names(run, tmp_path, capsys):
    """The reconstructions a spec names are inputs: ``--out`` inside one (or one itself) is
    refused before anything is written, and the evidence folder is left as it was (the audit
    of 4 December 2026 found ``validate --spec S --out REC/val`` writing into REC)."""
    import json

    from impress_gui.cli import main

    spec = json.loads((run["out"] / "validation-spec.json").read_text())
    rec_dir = Path(spec["scans"][0]["reconstruction"])
    if not rec_dir.is_absolute():
        rec_dir = (run["out"] / rec_dir).resolve()
    before = sorted(p.name for p in rec_dir.iterdir())
    for out in (rec_dir / "val", rec_dir):
        code = main(["validate", "--spec", str(run["out"] / "validation-spec.json"), "--out",
                     str(out), "--no-figures"])
        err = capsys.readouterr().err
        assert code == 2 and "E-OUTPUT-HOLDS-INPUT" in err, err
    assert sorted(p.name for p in rec_dir.iterdir()) == before


def test_a_heightmap_changed_after_processing_is_not_measured(run, tmp_path, capsys):
    """A reconstruction whose heightmap.tif no longer matches the SHA-256 its metadata.json
    records is refused (as cast and compare refuse it), not measured and recorded under the
    original's hash (the audit of 4 December 2026: heights doubled, the step read twice as
    high, the old hash in validation.json, exit 0)."""
    import shutil

    import tifffile

    from impress_gui.cli import main

    spec = json.loads((run["out"] / "validation-spec.json").read_text())
    for s in spec["scans"]:
        src = Path(s["reconstruction"])
        if not src.is_absolute():
            src = (run["out"] / src).resolve()
        dst = tmp_path / "recs" / s["name"]
        shutil.copytree(src, dst)
        s["reconstruction"] = str(dst)
    first = tmp_path / "recs" / spec["scans"][0]["name"] / "heightmap.tif"
    height = tifffile.imread(first)
    tifffile.imwrite(first, height * 2, compression="zlib")
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    code = main(["validate", "--spec", str(tmp_path / "spec.json"), "--out",
                 str(tmp_path / "val"), "--no-figures"])
    err = capsys.readouterr().err
    assert code == 2 and "E-VALIDATE-HASH" in err and "changed after processing" in err, err
    assert not (tmp_path / "val" / "validation.json").exists()


def test_a_run_keeps_only_what_its_record_and_report_need(run):
    """A quick run wrote about 2 GB (issue 21, item 13): each reconstruction now keeps the
    fused heightmap it was measured on and the records naming every file with its SHA-256;
    the real-scan spec made from the run still measures it (test above)."""
    from impress_gui.validation.run import KEPT_FILES

    for scan in run["record"]["scans"]:
        folder = Path(scan["reconstruction"]["path"])
        left = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
        assert left == sorted(KEPT_FILES)
        assert "pointcloud.ply" in scan["reconstruction"]["pruned"]
        meta = json.loads((folder / "metadata.json").read_text())
        assert "pointcloud.ply" in meta["files"]  # its hash stays on record


def test_cancel_stops_a_run(tmp_path):
    token = CancelToken()
    token.cancel()
    with pytest.raises(Cancelled):
        run_simulated(RunConfig.quick(**QUICK), tmp_path, cancel=token)


def test_bad_specs_are_refused(tmp_path):
    good = {
        "format": "impress.validation-spec",
        "version": 1,
        "scans": [
            {
                "name": "s",
                "reconstruction": "r",
                "measurements": [
                    {
                        "id": "a",
                        "kind": "step",
                        "nominal_mm": 6.35,
                        "start_mm": [0, 0],
                        "end_mm": [10, 0],
                        "band_a_mm": [1, 2],
                        "band_b_mm": [5, 6],
                    }
                ],
            }
        ],
    }
    p = tmp_path / "spec.json"
    write_json(p, good)
    assert load_spec(p)[1][0].readings[0].kind == "step"
    bad = [
        ("kind", "volume"),
        ("nominal_mm", -1),
        ("start_mm", [0]),
        ("band_a_mm", None),
        ("id", ""),
    ]
    for key, value in bad:
        doc = json.loads(json.dumps(good))
        doc["scans"][0]["measurements"][0][key] = value
        write_json(p, doc)
        with pytest.raises(FormatError) as err:
            load_spec(p)
        assert err.value.code == "E-VAL-SPEC", key
    doc = json.loads(json.dumps(good))
    doc["scans"][0]["measurements"] *= 2
    write_json(p, doc)
    with pytest.raises(FormatError, match="unique"):
        load_spec(p)


def test_a_missing_wall_fails_instead_of_measuring_the_next_one():
    """Two 4 mm slots 6 mm apart on a 20 mm block; the first slot's far wall has no data around
    it: its width is a failed reading, not the distance to the next slot's wall."""
    spec = GridSpec(0.0, 0.0, 0.1, (50, 400))
    xs = spec.xs()
    h = np.full(spec.shape, 20.0, np.float32)
    for a in (10.0, 20.0):
        h[:, (xs >= a) & (xs < a + 4.0)] = 14.0
    floor, top = (10.5, 13.5), (4.0, 9.5)
    walls = (V.Edge(floor, top, 10.0, 1.5), V.Edge(floor, (14.5, 19.5), 14.0, 1.5))
    r = V.Reading("w", "g", "A", "edge_distance", 4.0, (0.0, 2.5), (39.0, 2.5), edges=walls)
    d = V.Reading(
        "d", "g", "A", "step", 4.0 + 2.0, (0.0, 2.5), (39.0, 2.5), band_a_mm=top, band_b_mm=floor
    )
    ok = V.measure_all(h, spec, [r, d])
    assert ok[0].error_mm == pytest.approx(0.0, abs=0.06) and ok[1].measured_mm == 6.0
    h[:, (xs >= 12.5) & (xs < 17.0)] = np.nan  # the far wall and its surroundings lost
    bad = V.measure_reading(h, spec, r)
    assert math.isnan(bad.measured_mm) and bad.note.startswith("failed")
    assert V.stats([bad.error_mm, 0.1]).failed == 1


# ----- the VDI/VDE 2634-2 quantities on exact surfaces -------------------------------------------
def test_flatness_of_a_tilted_noisy_plane():
    spec = GridSpec(0.0, 0.0, 0.1, (400, 500))
    rng = np.random.default_rng(1)
    h = (0.02 * spec.xs()[None, :] - 0.01 * spec.ys()[:, None] + 2.0).astype(np.float32)
    h += rng.uniform(-0.05, 0.05, h.shape).astype(np.float32)
    h[10, 10] = 5.0  # one outlier: in the range, trimmed from the flatness
    f = VDI.flatness(h, spec, (1.0, 49.0), (1.0, 39.0), expected_mm=2.0 + 0.02 * 25 - 0.01 * 20)
    assert f.flatness_mm == pytest.approx(0.1, abs=0.01)
    assert f.range_mm > 2.5 and abs(f.offset_mm) < 0.01
    assert f.tilt_deg == pytest.approx(math.degrees(math.atan(math.hypot(0.02, 0.01))), abs=1e-3)


def test_sphere_fit_diameter_and_spacing():
    spec = GridSpec(-40.0, -40.0, 0.1, (800, 1200))
    xs, ys = np.meshgrid(spec.xs(), spec.ys())
    h = np.zeros(spec.shape, np.float32)
    rng = np.random.default_rng(2)
    spheres = [(-20.0, 0.0, 0.0, 12.7), (30.0, 5.0, -1.0, 12.7)]
    for x, y, z, r in spheres:
        d2 = (xs - x) ** 2 + (ys - y) ** 2
        cap = z + np.sqrt(np.clip(r * r - d2, 0, None))
        h = np.where(d2 < r * r, np.maximum(h, cap), h).astype(np.float32)
    h += rng.normal(0, 0.01, h.shape).astype(np.float32)
    out = VDI.sphere_errors(h, spec, spheres)
    assert out["failed"] == 0 and out["diameter"]["max_abs_mm"] < 0.01
    assert out["spacing"]["n"] == 1 and out["spacing"]["max_abs_mm"] < 0.01
    assert out["form_max_mm"] < 0.07
    # a sphere 0.1 mm too large is seen as such
    big = [(x, y, z, r - 0.05) for x, y, z, r in spheres]
    assert VDI.sphere_errors(h, spec, big)["diameter"]["mean_abs_mm"] == pytest.approx(
        0.1, abs=0.01
    )


# ----- the dialog and the menu -------------------------------------------------------------------
@pytest.mark.qt_log_ignore("propagateSizeHints", r"does not support raise\(\)")
def test_the_dialog_runs_a_spec_and_shows_the_table(qtbot, run, tmp_path):
    from measure_scans import guard_pyside_none
    from PySide6.QtCore import QSettings

    from impress_gui.ui.main_window import MainWindow

    guard_pyside_none()
    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    win = MainWindow(settings)
    qtbot.addWidget(win)
    try:
        dlg = win.open_validation()
        assert dlg.isVisible() and win.validation_action.text() == "Method &validation..."
        dlg.mode.setCurrentIndex(2)
        dlg.spec_edit.setText(str(run["out"] / "validation-spec.json"))
        dlg.out_edit.setText(str(tmp_path / "out"))
        with qtbot.waitSignal(dlg.finished_run, timeout=120_000):
            assert dlg.run()
        assert dlg.table.rowCount() == 2  # Order AB and Overall
        assert dlg.table.item(0, 0).text() == "Order AB"
        assert dlg.table.item(0, 6).text() == "0.540"
        assert dlg.report_button.isEnabled() and dlg.report_path.is_file()
        assert "Acceptance" in dlg.text.toPlainText()
        # a damaged spec: a message, no crash
        (tmp_path / "bad.json").write_text("{")
        dlg.spec_edit.setText(str(tmp_path / "bad.json"))
        with qtbot.waitSignal(dlg.worker.failed, timeout=30_000):
            dlg.run()
        assert "[E-JSON]" in win.messenger.last_text
    finally:
        win.shutdown()


def test_incomplete_readings_fail_alone_and_serialise():
    """A reading built in code without its bands fails by itself (not the whole run), and
    the spec writer keeps whichever band is present (bugs found by mypy)."""
    from impress_gui.validation.spec import reading_to_json

    spec = GridSpec(0.0, 0.0, 0.1, (200, 200))
    yy, xx = np.mgrid[0:200, 0:200]
    height = np.where(xx < 100, 5.0, 0.0).astype(np.float32)  # a 5-mm step across x = 10 mm
    base = dict(group="g", target="t", nominal_mm=5.0, start_mm=(2.0, 10.0), end_mm=(18.0, 10.0))
    good = V.Reading(id="ok", kind="step", band_a_mm=(1.0, 6.0), band_b_mm=(10.0, 15.0), **base)
    no_b = V.Reading(id="no_b", kind="step", band_a_mm=(1.0, 6.0), **base)
    no_around = V.Reading(id="w", kind="width", band_a_mm=(1.0, 6.0), band_b_mm=(10.0, 15.0),
                          **base)
    results = V.measure_all(height, spec, [good, no_b, no_around])
    assert results[0].measured_mm == pytest.approx(5.0, abs=1e-4)
    assert math.isnan(results[1].measured_mm) and "band_b_mm" in results[1].note
    assert math.isnan(results[2].measured_mm) and "around_mm" in results[2].note
    doc = reading_to_json(no_b)
    assert doc["band_a_mm"] == [1.0, 6.0] and "band_b_mm" not in doc


def test_the_method_component_comes_from_a_validation_record(run, tmp_path):
    """issue 22, component 6: the run's record gives the method's height bias and SD (the
    mean and SD of its z readings' signed errors, computed here from the saved JSON); a height
    budget with it gains "method (validation)" of u = sqrt(bias^2 + SD^2) and a larger U; the
    session keeps the record (with the file's SHA-256) in the project, through a save and a
    load; what is not a validation record is refused with its code and changes nothing."""
    import hashlib

    from impress_gui.core.base import codes
    from impress_gui.core.measure import readings as M
    from impress_gui.core.measure import uncertainty as U
    from impress_gui.core.project.project import Project
    from impress_gui.session.session import Session
    from impress_gui.validation.method import SETTINGS_KEY, budget_validation, method_record

    path = run["out"] / "validation.json"
    saved = json.loads(path.read_text())
    z = np.array([r["error_mm"] for r in saved["readings"]
                  if r["axis"] == "z" and r["error_mm"] is not None])
    assert len(z) >= 3
    rec = method_record(path)
    assert rec["z"]["n"] == len(z)
    assert rec["z"]["bias_mm"] == pytest.approx(z.mean(), abs=1e-12)
    assert rec["z"]["sd_mm"] == pytest.approx(z.std(ddof=1), abs=1e-12)
    assert rec["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    # a height budget on a noisy plane, without and with the method
    spec = GridSpec(0.0, 0.0, 0.1, (200, 200))
    h = np.random.default_rng(1).normal(0, 0.03, spec.shape).astype(np.float32)
    ro = M.readout(h, spec, 10.0, 10.0, 0.5)
    plain = U.height_budget(U.UncertaintyContext(h, spec), ro)
    ctx = U.UncertaintyContext(h, spec, validation=budget_validation(rec))
    with_method = U.height_budget(ctx, ro)
    comp = next(c for c in with_method.components if c.name == "method (validation)")
    assert comp.u_mm == pytest.approx(math.hypot(z.mean(), z.std(ddof=1)), rel=1e-9)
    assert with_method.u_c_mm == pytest.approx(math.hypot(plain.u_c_mm, comp.u_mm), rel=1e-6)
    assert "validation.json" in comp.note and rec["sha256"][:12] in comp.note
    assert not any("validate report: not included" in n for n in with_method.notes)
    # kept by the session in the project, through a save and a load
    session = Session(Project(case_id="V-6"))
    session.set_method_validation(path)
    assert session.method_validation == rec
    session.project.save(tmp_path / "case")
    back = Project.load(tmp_path / "case")
    assert back.calibration_settings[SETTINGS_KEY] == rec
    # refused: another kind of JSON, and a record without height readings
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"format": "impress.picks", "version": 1}))
    thin = tmp_path / "thin.json"
    thin.write_text(json.dumps({**saved, "readings": [r for r in saved["readings"]
                                                       if r["axis"] != "z"]}))
    for bad in (other, thin):
        with pytest.raises(FormatError) as err:
            session.set_method_validation(bad)
        assert err.value.code in (codes.E_FORMAT, codes.E_WRONG_FORMAT)
        assert session.method_validation == rec  # unchanged
    session.set_method_validation(None)
    assert session.method_validation is None


def test_an_interrupted_validation_leaves_no_folder_behind(tmp_path):
    # a hostile-input audit: Ctrl-C left the output folder with its mark and an empty scans/
    from impress_gui.core.base.progress import CancelToken
    from impress_gui.validation.run import RunConfig, run_simulated

    token = CancelToken()
    token.cancel()
    with pytest.raises(Cancelled):
        run_simulated(RunConfig.quick(), tmp_path / "v", cancel=token)
    assert not (tmp_path / "v").exists()
    # a folder that was there is left as it was
    (tmp_path / "w").mkdir()
    with pytest.raises(Cancelled):
        run_simulated(RunConfig.quick(), tmp_path / "w", cancel=token)
    assert (tmp_path / "w").is_dir()


def test_the_uncertainty_trials_are_checked_before_anything_runs(tmp_path, capsys):
    """``--uncertainty-trials`` outside 4..1000 is refused with the option's code, before a
    scan is rendered; nothing is written."""
    from impress_gui.cli import main

    with pytest.raises(InputError, match="uncertainty trials 2"):
        RunConfig.quick(uncertainty_trials=2).validate()
    out = tmp_path / "v"
    code = main(["validate", "--quick", "--uncertainty-trials", "3", "--out", str(out)])
    err = capsys.readouterr().err
    assert code != 0 and "uncertainty trials 3" in err and "Traceback" not in err
    assert not out.exists()
