"""HTML to PDF through Qt's own text layout (QTextDocument printed on a QPdfWriter): the case
report as a PDF, the format courts and case files take, with real text (searchable, copyable)
and the figures embedded. Safe in a worker thread (no widget is involved)."""

from __future__ import annotations

import base64
import re

from PySide6.QtCore import QBuffer, QByteArray, QIODevice, QMarginsF, QUrl
from PySide6.QtGui import (
    QFont,
    QImage,
    QPageLayout,
    QPageSize,
    QPdfWriter,
    QTextCharFormat,
    QTextCursor,
    QTextDocument,
)

_DATA_URI = re.compile(r"""src=(['"])data:image/png;base64,([A-Za-z0-9+/=]+)\1""")


def html_to_pdf(html: str, title: str, creator: str) -> bytes:
    """``html`` (inline PNG images as data URIs) as an A4 PDF; ``title`` and ``creator`` go
    into the PDF's document information. Text is laid out without ligatures, so that hashes
    and identifiers copied out of the PDF are the characters written."""
    doc = QTextDocument()
    images: list[bytes] = []

    def resource(m: re.Match) -> str:
        images.append(base64.b64decode(m.group(2)))
        return f"src='image{len(images)}.png'"

    html = _DATA_URI.sub(resource, html)
    for k, data in enumerate(images, start=1):
        image = QImage.fromData(data)
        if image.width() > 1600:  # the page is 1600 layout units wide at most
            image = image.scaledToWidth(1600)
        doc.addResource(QTextDocument.ResourceType.ImageResource, QUrl(f"image{k}.png"), image)
    doc.setHtml(html)
    # no ligatures: "ff" in a SHA-256 would otherwise become one glyph (U+FB00) that a reader
    # copies out of the PDF as another character, and the hash no longer verifies
    cursor = QTextCursor(doc)
    cursor.select(QTextCursor.SelectionType.Document)
    plain = QTextCharFormat()
    plain.setFontStyleStrategy(QFont.StyleStrategy.PreferNoShaping)
    cursor.mergeCharFormat(plain)
    data = QByteArray()
    buffer = QBuffer(data)
    buffer.open(QIODevice.OpenModeFlag.WriteOnly)
    writer = QPdfWriter(buffer)
    writer.setPageLayout(QPageLayout(QPageSize(QPageSize.PageSizeId.A4),
                                     QPageLayout.Orientation.Portrait,
                                     QMarginsF(15, 15, 15, 15), QPageLayout.Unit.Millimeter))
    writer.setResolution(300)
    writer.setTitle(title)
    writer.setCreator(creator)
    doc.print_(writer)
    del writer  # finishes the file
    buffer.close()
    return bytes(data)
