"""Presentation of the figures and plots (issue 21 item 9): the figure's title wrapped over the
whole width, never sharing its rows with the colour bar's label; the colour bar's label
(the difference layer's "green-red (mm)") whole and clear of the bar's tick labels; a legend
for the contribution layer in the figure and in the viewer's display panel; the profile PNG
drawn as a figure (title, case, source, axes in mm, bands) with its provenance text chunks;
the lookup-table plots from 0 with a colour bar."""

from __future__ import annotations

import json

import numpy as np
import pyqtgraph as pg
import pytest

from impress_gui.core.formats import provenance as P
from impress_gui.core.formats.figures import BAND_RGB, figure, profile_figure
from impress_gui.core.formats.writers import contribution_png
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.ui.viewer.map import CONTRIBUTION_LEGEND

pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints")]
LONG_TITLE = (
    "Case C-2026-000117-LONG-IDENTIFIER, evidence E-0004-LEFT-SHOE-HEEL: "
    "Difference green - red (levelled)"
)


def _ink(img: np.ndarray) -> np.ndarray:
    return (np.asarray(img) < 200).any(axis=2)


def _difference_figure(title: str, unit: str = "green-red (mm)") -> np.ndarray:
    spec = GridSpec(-10.0, 0.0, 0.1, (900, 250))  # a narrow map: the title is wider
    y = np.linspace(-0.4, 0.3, spec.shape[0], dtype=np.float32)
    h = np.repeat(y[:, None], spec.shape[1], axis=1)
    lut = pg.colormap.get("turbo").getLookupTable(nPts=256)
    return figure(spec, height=h, lut=lut, vrange=(-0.39, 0.28), title=title, unit_label=unit)


def _title_mask(title: str) -> tuple[np.ndarray, np.ndarray]:
    """The figure with ``title`` and where its title's ink is (against an untitled one,
    aligned at the bottom: the title rows are on top)."""
    with_title, without = _difference_figure(title), _difference_figure("")
    assert with_title.shape[1] == without.shape[1]
    n = without.shape[0]
    diff = np.zeros(with_title.shape[:2], bool)
    diff[-n:] = (with_title[-n:] != without).any(axis=2)
    diff[:-n] = _ink(with_title[:-n])
    return with_title, diff


def test_the_title_is_whole_and_shares_no_row_with_the_colour_bar_label():
    fig, title = _title_mask(LONG_TITLE)
    rows = np.flatnonzero(title.any(axis=1))
    assert rows.size
    # nothing but the title is drawn in the title's rows (the bar's label is below them)
    other = _ink(fig) & ~title
    assert not other[rows.min() : rows.max() + 1].any()
    # wrapped inside the figure, not cut at its edge
    cols = np.flatnonzero(title.any(axis=0))
    assert cols.max() < fig.shape[1] - 5
    runs = np.flatnonzero(np.diff(rows) > 3)
    assert len(runs) >= 1  # the long title takes two lines


def test_the_colour_bar_label_is_whole_and_clear_of_the_bar():
    fig, title = _title_mask(LONG_TITLE)
    ink = _ink(fig) & ~title
    # nothing cut at the figure's right edge
    assert not ink[:, -3:].any()
    # the bar: the right-most column block of saturated colour
    sat = (fig.max(axis=2).astype(int) - fig.min(axis=2)) > 80
    bar_cols = np.flatnonzero(sat.sum(axis=0) > fig.shape[0] // 3)
    bar_top = int(np.flatnonzero(sat[:, bar_cols[-1]]).min())
    panel = ink[:, bar_cols.min() - 8 :]
    above = np.flatnonzero(panel[:bar_top].any(axis=1))
    # above the bar: the label's line, then a white gap, then the top tick's label
    gaps = np.flatnonzero(np.diff(above) > 2)
    assert len(gaps) >= 1, "the label touches the bar's tick label"
    label_rows = above[: gaps[0] + 1]
    assert label_rows.max() < bar_top - 10


def test_the_contribution_figure_has_a_legend():
    spec = GridSpec(0.0, 0.0, 0.1, (300, 400))
    codes = np.full(spec.shape, 3, np.uint8)  # the map itself holds no green, red nor orange
    rgb = contribution_png(codes)
    fig = figure(spec, rgb=rgb, title="contribution", legend=CONTRIBUTION_LEGEND,
                 legend_title="Which laser measured the cell")
    colours = {tuple(c) for c, _t in CONTRIBUTION_LEGEND}
    assert {(40, 200, 40), (220, 40, 40), (230, 230, 230), (0, 0, 0)} <= colours
    for c in colours - {(230, 230, 230), (0, 0, 0)}:
        hit = (fig == np.array(c, np.uint8)).all(axis=2)
        assert hit.sum() >= 100, f"no swatch of {c}"
    texts = [t for _c, t in CONTRIBUTION_LEGEND]
    assert "green laser only" in texts and "red laser only" in texts and "no data" in texts


def test_the_display_panel_shows_the_contribution_legend(qtbot):
    from test_gui_viewer import make_viewer  # noqa: F401 - guards PySide as that module does

    from impress_gui.ui.viewer.panels import DisplayPanel

    p = DisplayPanel()
    qtbot.addWidget(p)
    p.show()
    assert p.legend.isHidden()
    p.set_layer("contribution")
    assert not p.legend.isHidden() and p.legend.isVisible()
    assert "green laser only" in p.legend.text() and "red laser only" in p.legend.text()
    p.set_layer("fused")
    assert p.legend.isHidden()


def test_profile_figure_axes_and_bands():
    d = np.linspace(0, 40, 401)
    z = np.where((d > 15) & (d < 25), -2.0, 0.0)
    z[100:110] = np.nan
    plain = profile_figure(d, z, title="Depth profile", lines=["Case X, evidence Y"])
    assert plain.shape == (1000, 2000, 3)
    a_colour = np.array(BAND_RGB["A"], np.uint8)
    assert not (plain == a_colour).all(axis=2).any()
    banded = profile_figure(d, z, title="Depth profile", bands={"A": (2, 10), "B": (17, 23)},
                            band_means={"A": 0.0, "B": -2.0})
    assert (banded == a_colour).all(axis=2).sum() > 100
    assert (banded == np.array(BAND_RGB["B"], np.uint8)).all(axis=2).sum() > 100


def test_profile_png_is_a_figure_with_case_and_provenance(qtbot, tmp_path):
    import cv2
    from test_export_provenance import _export, make_recon
    from test_gui_viewer import make_viewer

    folder = tmp_path / "recon"
    make_recon(folder)
    v = make_viewer(qtbot)
    try:
        with qtbot.waitSignal(v.loaded, timeout=30000):
            v.open_reconstruction(folder)
        v.project.case_id, v.project.evidence_id = "C-7", "E-3"
        with qtbot.waitSignal(v.profile_changed, timeout=10000):
            v.set_ruler((-6.0, 25.0), (6.0, 25.0))
        png = _export(qtbot, v, v.actions.export_profile_png, tmp_path / "p.png")
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
        assert img.shape[:2] == (1000, 2000)  # not a screen grab of the plot
        text = P.read_png_text(png)
        assert text["Software"] == P.SOFTWARE
        prov = json.loads(text[P.PNG_KEY])
        assert prov["export"] == "profile-png"
        assert prov["parameters"]["width_mm"] == pytest.approx(v.profile.width_mm)
        make = v.actions.profile_maker()
        np.testing.assert_array_equal(make(), img)
        # no band drawn until both are placed; then both are
        assert not (img == np.array(BAND_RGB["A"], np.uint8)).all(axis=2).any()
        with qtbot.waitSignal(v.profile_changed, timeout=10000):
            v.set_bands((1.0, 4.0), (5.0, 7.0))
        banded = v.actions.profile_maker()()
        assert (banded == np.array(BAND_RGB["A"], np.uint8)).all(axis=2).sum() > 100
    finally:
        v.shutdown()
        v.messenger.close_all()


def test_lut_plots_start_at_zero_with_a_colour_bar(qtbot):
    from test_gui_viewer import make_viewer  # noqa: F401 - guards PySide as that module does

    from impress_gui.ui.processing.panels import LutView

    view = LutView()
    qtbot.addWidget(view)
    view.resize(900, 300)
    view.show()
    qtbot.waitExposed(view)
    t = np.full((64, 64), -1, np.int16)
    t[:30, :40] = 200
    view.set_tables({"green": t, "red": t.T.copy()})
    qtbot.wait(50)

    def drawn() -> None:
        bars = [i for i in view.ci.items if isinstance(i, pg.ColorBarItem)]
        plots = [i for i in view.ci.items if isinstance(i, pg.PlotItem) and i not in bars]
        assert len(plots) == 2
        for p in plots:
            (x0, x1), (y0, y1) = p.getViewBox().viewRange()
            assert x0 >= 0 and y0 >= 0 and x1 >= 63 and y1 >= 63, ((x0, x1), (y0, y1))
        assert len(bars) == 1 and bars[0].isVisible()
        assert tuple(bars[0].levels()) == (0, 255)

    qtbot.waitUntil(drawn, timeout=5000)  # on a busy machine the ranges may settle later


def test_the_viewer_colour_bar_label_stays_beside_the_bar(qtbot):
    """Difference after contribution (the bar hidden, then shown with a new label): the label
    beside the bar, not over it."""
    from test_gui_viewer import make_viewer  # noqa: F401 - guards PySide as that module does

    from impress_gui.ui.viewer.map import MapView

    m = MapView()
    qtbot.addWidget(m)
    m.resize(1000, 650)
    m.show()
    qtbot.waitExposed(m)
    m.set_spec(GridSpec(0.0, 0.0, 1.0, (100, 100)))
    a = np.random.default_rng(1).random((100, 100)).astype(np.float32)
    try:
        m.show_scalar(a, (0.0, 1.0), "turbo")
        m.show_rgb(contribution_png(np.full((100, 100), 3, np.uint8)), nearest=True)
        m.show_scalar(a, (-0.4, 0.3), "turbo", "green - red (mm)")
        qtbot.wait(100)

        def beside() -> None:
            axis = m.colour_bar.getAxis("left")
            assert axis.width() > 5
            label = axis.label.mapRectToScene(axis.label.boundingRect())
            bar = m.colour_bar.bar.sceneBoundingRect()
            assert label.right() <= bar.left() + 1, (label, bar)

        qtbot.waitUntil(beside, timeout=5000)  # on a busy machine the layout settles later
    finally:
        m.shutdown()


def test_report_shows_parameters_as_tables_not_python_dicts():
    """The case report printed the processing parameters as raw Python dicts (issue 21, item
    12): a mapping is a small table, a list its items, a flag yes/no; the text is escaped."""
    from impress_gui.core.formats.figures import report_html

    html = report_html(
        case={"case_id": "C-1", "evidence_id": "E-2"},
        reconstruction={"parameters": {"method": "combined", "grid_mm": 0.1, "texture": True,
                                       "rois": {"green": [600, 800]}},
                        "frames": [12, 480], "note": "<b>x</b>"},
        calibration=None, measurements=[], images=[], inputs={}, created_utc="2026-11-24",
    )
    assert "{'" not in html and "[600" not in html
    assert "<table class='inner'><tr><th>method</th><td>combined</td></tr>" in html
    assert "<th>texture</th><td>yes</td>" in html and "<th>grid mm</th><td>0.1000</td>" in html
    assert "<td>12, 480</td>" in html and "&lt;b&gt;x&lt;/b&gt;" in html


def test_report_measurements_keep_a_readable_table_whatever_their_values():
    """A measurement's values are one cell (a small table of their own), not one column each:
    with a ruler's five values and their uncertainties as columns, the PDF's A4 table broke
    its words letter by letter (the label "slot width" was no longer in the text)."""
    from impress_gui.core.formats.figures import report_html

    values = {f"value_{k}_mm": 0.1 * k for k in range(12)}
    html = report_html(
        case={"case_id": "C-1"}, reconstruction={}, calibration=None,
        measurements=[{"kind": "ruler", "label": "slot width", "note": "",
                       "points_mm": [[1.0, 2.0], [3.0, 4.0]], "values": values}],
        images=[], inputs={}, created_utc="2026-11-25",
    )
    head = html[html.index("<h2>Measurements</h2>"):]
    head = head[:head.index("</tr>")]
    assert head.count("<th>") == 6  # #, kind, label, note, points, values
    assert "<th>value 11 mm</th><td>1.1000</td>" in html and "slot width" in html
