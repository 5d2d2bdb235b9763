"""The PDF writer (ui/pdf.py) keeps every character as written: no ligatures, so a SHA-256
copied out of a report PDF (read back by pypdf, not ours) verifies."""

from __future__ import annotations

import io

import pypdf


def test_hashes_and_words_come_back_without_ligatures(qapp):
    from impress_gui.ui.pdf import html_to_pdf

    digest = "511428ff1897538f1274862f78e8c3bfbe354cda8b690241dc9e8d83c8e12fd3"
    html = (f"<h1>Report</h1><p>office, fine, flat, affix</p>"
            f"<table><tr><td>heightmap.tif</td><td>{digest}</td></tr></table>")
    reader = pypdf.PdfReader(io.BytesIO(html_to_pdf(html, "t", "c")))
    text = "".join(page.extract_text() for page in reader.pages)
    assert not any("\ufb00" <= ch <= "\ufb06" for ch in text)  # ff, fi, fl, ffi, ffl, ...
    assert "office" in text and "affix" in text
    assert digest in "".join(text.split())
