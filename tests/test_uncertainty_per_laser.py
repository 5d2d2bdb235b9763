"""Where the two lasers disagreed (contribution code 4) the fusion kept one laser's value; with
the per-laser height maps (``UncertaintyContext.per_laser``) the budget moves such a cell as that
laser, without them as the lasers' mean (issue 22). The viewer and ``impress validate`` give the
budget the reconstruction's maps: from memory, or read from the result folder's TIFF layers
(:func:`~impress_gui.core.measure.uncertainty.per_laser_maps`); absent layers give None.

The calibration's Monte Carlo is a stub here whose trials lift every green cell by ``g`` and
every red cell by ``r`` (independent, 0.3 mm SD): a reading's calibration component is then
known exactly for each way a cell can be moved."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
import tifffile
from recon_data import recon_data_from_arrays

from impress_gui.core.formats.recon_files import LAYER_FILES
from impress_gui.core.measure import readings as M
from impress_gui.core.measure import uncertainty as U
from impress_gui.core.reconstruction.grid import GridSpec

S = 400
SPEC = GridSpec(0.0, 0.0, 0.1, (40, 60))
RNG = np.random.default_rng(11)
LIFT = {"green": RNG.normal(0.0, 0.3, S), "red": RNG.normal(0.0, 0.3, S)}


class _Ensemble:
    """A calibration Monte Carlo whose trial ``s`` lifts the cells of laser ``l`` by
    ``LIFT[l][s]`` and does not move them across the map."""

    n_trials = S
    click_sigma_px = 0.5
    sigma_source = "stub"
    summary: dict = {}
    nominal = SimpleNamespace(ref=np.zeros((1, 3)))

    def deltas(self, x, y, h, laser):
        n = np.atleast_1d(x).size
        z = np.zeros((S, n))
        return z, z.copy(), z + LIFT[laser][:, None]


def _maps():
    """Green reads 1.0 mm, red 1.8 mm. Columns 0-19: green only (code 1); 20-39: both,
    disagreeing, the fusion kept green (code 4); 40-59: both, disagreeing, kept red (code 4)."""
    green = np.full(SPEC.shape, 1.0, np.float32)
    red = np.full(SPEC.shape, 1.8, np.float32)
    fused = green.copy()
    fused[:, 40:] = red[:, 40:]
    code = np.full(SPEC.shape, 4, np.uint8)
    code[:, :20] = 1
    return fused, code, green, red


def _cal_u(budget: U.Budget) -> float:
    return next(c.u_mm for c in budget.components if c.name == "calibration")


def _ctx(per_laser) -> U.UncertaintyContext:
    fused, code, green, red = _maps()
    return U.UncertaintyContext(fused, SPEC, code, _Ensemble(), per_laser=per_laser)


def _sd(v) -> float:
    return float(np.std(v, ddof=1))


def test_the_per_laser_maps_change_a_disagreeing_cells_budget_as_designed():
    _, _, green, red = _maps()
    with_maps, without = _ctx({"green": green, "red": red}), _ctx(None)
    kept_red, kept_green, green_only = (5.0, 2.0), (3.0, 2.0), (1.0, 2.0)  # (x, y) mm
    g, r = LIFT["green"], LIFT["red"]

    # the height of a cell where the fusion kept red: red's calibration error, not the mean's
    fused = with_maps.height
    ro = M.readout(fused, SPEC, *kept_red, 0.0)
    assert _cal_u(U.height_budget(with_maps, ro)) == pytest.approx(_sd(r), rel=1e-9)
    assert _cal_u(U.height_budget(without, ro)) == pytest.approx(_sd((g + r) / 2), rel=1e-9)

    # a height difference from a green-only cell to a cell where the fusion kept green: both
    # move as green, so the calibration cancels; to a cell where it kept red it does not
    same = M.ruler(fused, SPEC, green_only, kept_green, 0.0)
    other = M.ruler(fused, SPEC, green_only, kept_red, 0.0)
    assert same.dz_mm == pytest.approx(0.0) and other.dz_mm == pytest.approx(0.8)
    assert _cal_u(U.ruler_budgets(with_maps, same)["dz"]) == pytest.approx(0.0, abs=1e-12)
    assert _cal_u(U.ruler_budgets(with_maps, other)["dz"]) == pytest.approx(_sd(r - g),
                                                                            rel=1e-9)
    # without the maps both code-4 cells move as the lasers' mean: half of the difference
    # for either, which hides the cancellation of the first and halves the second
    half = _sd((r - g) / 2)
    assert _cal_u(U.ruler_budgets(without, same)["dz"]) == pytest.approx(half, rel=1e-9)
    assert _cal_u(U.ruler_budgets(without, other)["dz"]) == pytest.approx(half, rel=1e-9)
    assert half > 0.1  # the two ways differ by far more than the stub's sampling


def test_a_levelled_reading_finds_the_kept_laser_on_the_unlevelled_heights():
    """The per-laser maps are unlevelled; on a levelled map the fused height is raised back
    by the plane before it is compared with them."""
    fused, code, green, red = _maps()
    plane = M.Plane(0.01, 0.0, 0.5)
    levelled = M.levelled(fused, SPEC, plane)
    ctx = U.UncertaintyContext(levelled, SPEC, code, _Ensemble(), level_plane=plane,
                               per_laser={"green": green, "red": red})
    assert ctx.lasers_at(5.0, 2.0) == [("red", 1.0)]
    assert ctx.lasers_at(3.0, 2.0) == [("green", 1.0)]
    assert ctx.lasers_at(1.0, 2.0) == [("green", 1.0)]  # code 1: green whatever the maps


def _write_layers(folder, names, arrays) -> None:
    for n in names:
        tifffile.imwrite(folder / LAYER_FILES[n], np.asarray(arrays[n], np.float32))


def test_per_laser_maps_come_from_memory_or_from_the_result_folder(tmp_path):
    fused, code, green, red = _maps()
    # in memory: the loaded layers themselves
    data = recon_data_from_arrays(SPEC, fused, contribution=code, green=green, red=red)
    maps = U.per_laser_maps(data)
    assert maps is not None and maps["green"] is data.layers["green"]
    assert maps["red"] is data.layers["red"]
    # not in memory: read from the folder's TIFF layers
    lean = dataclasses.replace(recon_data_from_arrays(SPEC, fused, contribution=code),
                               folder=tmp_path)
    assert U.per_laser_maps(lean) is None  # no layers written yet: None, no error
    _write_layers(tmp_path, ["green"], {"green": green})
    assert U.per_laser_maps(lean) is None  # one laser's map only: None
    _write_layers(tmp_path, ["red"], {"red": red})
    maps = U.per_laser_maps(lean)
    assert maps is not None and set(maps) == {"green", "red"}
    assert np.array_equal(maps["green"], green) and np.array_equal(maps["red"], red)
    assert maps["red"].dtype == np.float32 and not maps["red"].flags.writeable
    # and the budget made with them names the kept laser
    ctx = U.UncertaintyContext(fused, SPEC, code, _Ensemble(), per_laser=maps)
    assert ctx.lasers_at(5.0, 2.0) == [("red", 1.0)]
    # a layer of another grid or a damaged file is as good as absent
    tifffile.imwrite(tmp_path / LAYER_FILES["red"], np.zeros((3, 3), np.float32))
    assert U.per_laser_maps(lean) is None
    (tmp_path / LAYER_FILES["red"]).write_bytes(b"not a tiff")
    assert U.per_laser_maps(lean) is None
    # no folder and nothing in memory
    assert U.per_laser_maps(recon_data_from_arrays(SPEC, fused)) is None


@pytest.mark.qt_log_ignore("propagateSizeHints")
@pytest.mark.usefixtures("no_stray_python_threads")
def test_the_viewer_gives_its_budgets_the_folders_per_laser_maps(qtbot, tmp_path):
    """The viewer's context for the fused map carries the maps read from the result folder
    (once per reconstruction), and a reading on a cell where the fusion kept red moves as red;
    on a single laser's layer that laser is used whatever the maps say."""
    from gui_helpers import FakeDialogs
    from measure_scans import guard_pyside_none

    from impress_gui.ui import pyside_fix
    from impress_gui.ui.messages import Messenger
    from impress_gui.ui.viewer.tab import ViewerTab

    pyside_fix.guard()
    guard_pyside_none()
    fused, code, green, red = _maps()
    _write_layers(tmp_path, ["green", "red"], {"green": green, "red": red})
    data = dataclasses.replace(recon_data_from_arrays(SPEC, fused, contribution=code),
                               folder=tmp_path)
    v = ViewerTab(Messenger(None), FakeDialogs())
    qtbot.addWidget(v)
    try:
        with qtbot.waitSignal(v.loaded, timeout=20000):
            v.set_data(data)
        assert v.measure_key() == "fused"
        ctx = v.measurements.uncertainty.context()
        assert ctx is not None and ctx.per_laser is not None
        assert np.array_equal(ctx.per_laser["red"], red)
        assert ctx.lasers_at(5.0, 2.0) == [("red", 1.0)]
        assert ctx.lasers_at(3.0, 2.0) == [("green", 1.0)]
        # read once per reconstruction, not per reading
        assert v.measurements.uncertainty.context().per_laser is ctx.per_laser
        # another reconstruction without the layers: no maps, the lasers' mean as before
        with qtbot.waitSignal(v.loaded, timeout=20000):
            v.set_data(recon_data_from_arrays(SPEC, fused, contribution=code))
        ctx = v.measurements.uncertainty.context()
        assert ctx.per_laser is None
        assert ctx.lasers_at(5.0, 2.0) == [("green", 0.5), ("red", 0.5)]
    finally:
        v.shutdown()
        v.messenger.close_all()
