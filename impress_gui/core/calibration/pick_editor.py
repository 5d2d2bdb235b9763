"""The corner-marking state behind the calibration tab, with undo/redo (no Qt).

Two pick frames, ``"t1"`` (green stripe on the target) and ``"t2"`` (red stripe), each with
corners A-F in raw (distorted) image pixels, ``(0, 0)`` the centre of the top-left pixel. Every
change makes a new immutable :class:`PickState`; :meth:`PickEditor.undo` and
:meth:`PickEditor.redo` walk the history. A snapped corner remembers the raw click so the view
can show both and the user can undo the snap.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.target import CORNER_NAMES

FRAMES = ("t1", "t2")
Point = tuple[float, float]


@dataclass(frozen=True)
class PickState:
    t1: int | None = None
    t2: int | None = None
    corners_t1: dict[str, Point] = field(default_factory=dict)
    corners_t2: dict[str, Point] = field(default_factory=dict)
    raw_t1: dict[str, Point] = field(default_factory=dict)  # clicks before a snap
    raw_t2: dict[str, Point] = field(default_factory=dict)
    # the three-point fallback's stripe points of an imported picks file, kept unchanged
    stripe_points: dict = field(default_factory=dict)

    def frame(self, which: str) -> int | None:
        return self.t1 if which == "t1" else self.t2

    def corners(self, which: str) -> dict[str, Point]:
        return self.corners_t1 if which == "t1" else self.corners_t2

    def raw(self, which: str) -> dict[str, Point]:
        return self.raw_t1 if which == "t1" else self.raw_t2

    def with_corners(self, which: str, corners: dict, raw: dict) -> PickState:
        if which == "t1":
            return replace(self, corners_t1=corners, raw_t1=raw)
        return replace(self, corners_t2=corners, raw_t2=raw)


class PickEditor:
    """Mutable front of the pick history; ``on_change`` is called after every change."""

    def __init__(self, on_change: Callable[[], None] | None = None) -> None:
        self.state = PickState()
        self._undo: list[tuple[PickState, str]] = []
        self._redo: list[tuple[PickState, str]] = []
        self.on_change = on_change
        self.last_action = ""

    # ----- queries ------------------------------------------------------------------------
    def which_for_frame(self, k: int) -> str | None:
        """The pick frame ("t1"/"t2") shown at video frame ``k``, if any (t1 first)."""
        for which in FRAMES:
            if self.state.frame(which) == k:
                return which
        return None

    def next_corner(self, which: str) -> str | None:
        done = self.state.corners(which)
        return next((c for c in CORNER_NAMES if c not in done), None)

    def count(self, which: str) -> int:
        return len(self.state.corners(which))

    def is_complete(self) -> bool:
        s = self.state
        return (
            s.t1 is not None
            and s.t2 is not None
            and all(self.count(w) == len(CORNER_NAMES) for w in FRAMES)
        )

    def can_undo(self) -> bool:
        return bool(self._undo)

    def can_redo(self) -> bool:
        return bool(self._redo)

    @property
    def undo_label(self) -> str:
        return self._undo[-1][1] if self._undo else ""

    # ----- changes -------------------------------------------------------------------------
    def _push(self, new: PickState, action: str) -> None:
        if new == self.state:
            return
        self._undo.append((self.state, action))
        self._redo.clear()
        self.state = new
        self.last_action = action
        self._changed()

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change()

    def set_frame(self, which: str, k: int) -> None:
        """Make video frame ``k`` the pick frame ``which``; its corners (marked in another frame)
        are cleared, which undo restores."""
        if self.state.frame(which) == k:
            return
        new = replace(self.state, t1=int(k)) if which == "t1" else replace(self.state, t2=int(k))
        if self.count(which):
            new = new.with_corners(which, {}, {})
        self._push(new, f"set {which} to frame {k}")

    def place(self, which: str, uv: Point) -> str:
        """Mark the next corner of ``which`` at ``uv``; return its name."""
        if self.state.frame(which) is None:
            raise InputError(f"choose the frame {which} first", code=codes.E_PICKS)
        name = self.next_corner(which)
        if name is None:
            raise InputError(
                f"all six corners are already marked in {which}; drag a corner to "
                "move it, or clear the frame to start again",
                code=codes.E_PICKS,
            )
        corners = dict(self.state.corners(which))
        corners[name] = (float(uv[0]), float(uv[1]))
        raw = {k: v for k, v in self.state.raw(which).items() if k != name}
        self._push(self.state.with_corners(which, corners, raw), f"mark {name} in {which}")
        return name

    def snap(self, which: str, name: str, uv: Point) -> None:
        """Move a corner to its refined position, remembering the click (undo restores it)."""
        corners = dict(self.state.corners(which))
        raw = dict(self.state.raw(which))
        raw[name] = corners[name]
        corners[name] = (float(uv[0]), float(uv[1]))
        self._push(self.state.with_corners(which, corners, raw), f"snap {name} in {which}")

    def move(self, which: str, name: str, uv: Point) -> None:
        corners = dict(self.state.corners(which))
        corners[name] = (float(uv[0]), float(uv[1]))
        raw = {k: v for k, v in self.state.raw(which).items() if k != name}
        self._push(self.state.with_corners(which, corners, raw), f"move {name} in {which}")

    def clear(self, which: str) -> None:
        self._push(self.state.with_corners(which, {}, {}), f"clear the corners of {which}")

    def undo(self) -> str:
        if not self._undo:
            return ""
        prev, action = self._undo.pop()
        self._redo.append((self.state, action))
        self.state = prev
        self.last_action = f"undo {action}"
        self._changed()
        return action

    def redo(self) -> str:
        if not self._redo:
            return ""
        nxt, action = self._redo.pop()
        self._undo.append((self.state, action))
        self.state = nxt
        self.last_action = action
        self._changed()
        return action

    def reset(self, state: PickState | None = None) -> None:
        """Start a fresh history (a new video, a loaded project)."""
        self.state = state or PickState()
        self._undo.clear()
        self._redo.clear()
        self.last_action = ""
        self._changed()

    # ----- conversion ----------------------------------------------------------------------
    @staticmethod
    def state_of(picks: Picks) -> PickState:
        return PickState(picks.t1, picks.t2, dict(picks.corners_t1), dict(picks.corners_t2),
                         stripe_points=dict(picks.stripe_points))

    def load_picks(self, picks: Picks) -> None:
        """Start a fresh history from saved picks."""
        self.reset(self.state_of(picks))

    def import_picks(self, picks: Picks) -> None:
        """Replace the picks as one undoable step."""
        self._push(self.state_of(picks), "import picks")

    def to_picks(self, video: str, video_sha256: str | None = None, note: str = "") -> Picks | None:
        """The picks as the core takes them (None while t1 or t2 is not chosen)."""
        s = self.state
        if s.t1 is None or s.t2 is None:
            return None
        return Picks(
            video,
            s.t1,
            s.t2,
            dict(s.corners_t1),
            dict(s.corners_t2),
            video_sha256=video_sha256,
            note=note,
            stripe_points=dict(s.stripe_points),
        )
