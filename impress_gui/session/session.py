"""The working session (Qt-free, observable): what one examiner has open right now.

One :class:`Session` holds the open case project, the one reader on its evidence video, the
scene calibration in use and the reconstructions made or opened in this session. The window's
tabs are views over it: they change it through its methods and follow it through its signals
(psygnal, as napari's models do), so no tab keeps its own copy of the project or the
calibration, and no tab reaches into another. The command line drives the same jobs
(:mod:`impress_gui.session.calibration_jobs`, :mod:`impress_gui.session.processing_jobs`)
without a session object, as each command is one step.

Signals are emitted on the thread that calls the method; the window calls them on its GUI
thread only (results of background jobs arrive there through :class:`~impress_gui.ui.worker.Worker`).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from psygnal import EmitLoopError, Signal

from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.formats.video import VideoSource
from impress_gui.core.project.project import Project

FRAME_CACHE = 24  # decoded frames kept for browsing (1080p RGB: about 150 MB)


def _emit(signal, *args) -> None:
    """Emit, and let a listener's error through as itself (psygnal wraps it in EmitLoopError):
    a view refusing a project raises an ImpressError its caller shows with its code."""
    try:
        signal.emit(*args)
    except EmitLoopError as exc:
        if isinstance(exc.__cause__, Exception):
            raise exc.__cause__ from None
        raise


@dataclass(frozen=True)
class Evidence:
    """The evidence video as opened in this session: where, its SHA-256 (checked when it was
    opened) and the one reader the views browse it with."""

    path: Path
    sha256: str
    reader: VideoSource


class Session:
    """The open project, its evidence reader, its calibration and its reconstructions."""

    project_changed = Signal(object)  # the Project now open
    evidence_changed = Signal(object)  # Evidence, or None when closed
    calibration_changed = Signal(object)  # SceneCalibration or None
    reconstruction_added = Signal(object)  # Path of a reconstruction folder (made or opened)
    changed = Signal()  # something the case record keeps changed (title, unsaved mark)
    status = Signal(str)  # a line for the status bar

    def __init__(self, project: Project | None = None) -> None:
        self._project = project if project is not None else Project()
        self._evidence: Evidence | None = None
        self._frames: OrderedDict[int, np.ndarray] = OrderedDict()
        self._reconstructions: list[Path] = []

    # ----- the project ---------------------------------------------------------------------
    @property
    def project(self) -> Project:
        return self._project

    def open_project(self, project: Project) -> None:
        """Make ``project`` the open one: the evidence reader of the previous one is closed
        (the views open the new project's video themselves, after re-hashing it)."""
        self.close_evidence()
        self._project = project
        self._reconstructions = []
        _emit(self.project_changed, project)
        _emit(self.calibration_changed, project.calibration)
        _emit(self.changed)

    def log(self, action: str, details: dict | None = None) -> None:
        self._project.log(action, details or {})

    def mark_changed(self) -> None:
        """Something the project keeps changed (the views call this after editing it)."""
        _emit(self.changed)

    # ----- the evidence video ---------------------------------------------------------------
    @property
    def evidence(self) -> Evidence | None:
        return self._evidence

    def adopt_evidence(self, path: str | Path, reader: VideoSource, sha256: str,
                       new: bool) -> bool:
        """Make ``reader`` (opened on ``path``, whose SHA-256 is ``sha256``) the session's one
        evidence reader. ``new``: the user chose this video for the project; when it is another
        video than the project's, the picks and the calibration made on the old one are cleared.
        Returns True when those were cleared."""
        self.close_evidence()
        path = Path(path).resolve()
        cleared = False
        if new:
            p = self._project
            same = p.video is not None and p.video.sha256 == sha256
            p.set_video(path, sha256=sha256)
            if not same:
                had = p.calibration is not None
                p.set_picks(None)
                p.set_calibration(None)
                if had:
                    _emit(self.calibration_changed, None)
                cleared = True
        self._evidence = Evidence(path, sha256, reader)
        _emit(self.evidence_changed, self._evidence)
        if new:
            _emit(self.changed)
        return cleared

    def close_evidence(self) -> None:
        if self._evidence is None:
            return
        self._evidence.reader.close()
        self._evidence = None
        self._frames.clear()
        _emit(self.evidence_changed, None)

    def frame(self, k: int) -> np.ndarray:
        """Frame ``k`` of the evidence video as RGB (the last few are cached for browsing).
        Call from the GUI thread; background jobs open their own reader."""
        if self._evidence is None:
            raise LookupError("no evidence video is open")
        k = int(k)
        if k in self._frames:
            self._frames.move_to_end(k)
            return self._frames[k]
        rgb = self._evidence.reader.read(k)
        self._frames[k] = rgb
        while len(self._frames) > FRAME_CACHE:
            self._frames.popitem(last=False)
        return rgb

    # ----- the calibration -----------------------------------------------------------------
    @property
    def calibration(self) -> SceneCalibration | None:
        return self._project.calibration

    def set_calibration(self, cal: SceneCalibration | None, picks=None) -> None:
        """Record a scene calibration (with the picks it was made from) in the project."""
        if picks is not None:
            self._project.set_picks(picks)
        self._project.set_calibration(cal)
        _emit(self.calibration_changed, cal)
        _emit(self.changed)

    # ----- the method's validation (component 6 of the uncertainty budget) -------------------
    @property
    def method_validation(self) -> dict | None:
        """The ``impress validate`` record the budgets take the method's bias and precision
        from (:func:`~impress_gui.validation.method.method_record`), or None."""
        from impress_gui.validation.method import SETTINGS_KEY

        rec = self._project.calibration_settings.get(SETTINGS_KEY)
        return rec if isinstance(rec, dict) else None

    def set_method_validation(self, path: str | Path | None) -> dict | None:
        """Take the method's bias and precision from the validation record at ``path`` (None:
        leave the component out again); kept in the project's calibration settings, with the
        file's SHA-256, and logged. A file that is not a validation record raises FormatError
        and changes nothing."""
        from impress_gui.validation.method import SETTINGS_KEY, method_record

        settings = dict(self._project.calibration_settings)
        rec = None if path is None else method_record(path)
        if rec is None:
            settings.pop(SETTINGS_KEY, None)
        else:
            settings[SETTINGS_KEY] = rec
        self._project.set_calibration_settings(settings)
        _emit(self.changed)
        return rec

    # ----- reconstructions ------------------------------------------------------------------
    @property
    def reconstructions(self) -> list[Path]:
        return list(self._reconstructions)

    @property
    def current_reconstruction(self) -> Path | None:
        return self._reconstructions[-1] if self._reconstructions else None

    def add_reconstruction(self, folder: str | Path, sha256: str | None = None,
                           record: bool = True) -> None:
        """A reconstruction folder made (``record``: entered in the project's outputs with the
        SHA-256 of its metadata) or opened in this session; the viewer shows it."""
        folder = Path(folder)
        if record:
            self._project.add_output(folder / "metadata.json", "reconstruction", sha256=sha256)
        self._reconstructions = [p for p in self._reconstructions if p != folder] + [folder]
        _emit(self.reconstruction_added, folder)
        if record:
            _emit(self.changed)

    def close(self) -> None:
        self.close_evidence()
