"""Frames kept while decoding equal the frames read again by seeking (the texture's ends are
coloured from frames the reconstruction keeps as the decoder passes them, instead of seeking
them after the frame loop)."""

from __future__ import annotations

import numpy as np

from impress_gui.core.formats.video import open_video


def test_frames_kept_while_decoding_are_the_frames_read_again(flat_scan):
    with open_video(flat_scan / "scan.mp4") as video:
        n = video.frame_count
        wanted = (3, n // 2 + 1, n - 5)  # none of them a keyframe but the first frames' GOP
        keep: dict = dict.fromkeys(wanted)
        seen = 0
        for _k, planes in video.iter_planes(2, n - 2, keep):
            seen += 1
            assert planes.y.shape[1] == video.size[0]
        assert seen == n - 4
        for k in wanted:
            again = video.read(k)
            assert keep[k] is not None and keep[k].dtype == np.uint8
            assert keep[k].shape == again.shape == (video.size[1], video.size[0], 3)
            np.testing.assert_array_equal(keep[k], again)
        # a frame outside the range decoded stays unset
        keep2: dict = {0: None}
        for _ in video.iter_planes(1, 4, keep2):
            pass
        assert keep2[0] is None
