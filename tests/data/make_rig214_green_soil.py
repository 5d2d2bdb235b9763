"""Makes rig214_red_green_soil.npz (tests/test_faint_stripe.py) from the benchmark's cached render
of random rig 214 at 1920x1080 (simulator key e11ac3af15): a crop of frame 55, columns 900-1260,
around the red stripe where it crosses green soil - the red channel rises from about 17 to 33,
the luma by 4-5 grey levels - kept as decoded planes, with the renderer's exact stripe rows per
column (the same crop as make_rig214_dark.py makes, of another frame and render).

Run from the repository: .venv/bin/python tests/data/make_rig214_green_soil.py [FRAME] [OUT.npz]"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import make_rig214_dark  # noqa: E402

KEY = "e11ac3af15"
COLS = (900, 1260)

if __name__ == "__main__":
    make_rig214_dark.main(int(sys.argv[1]) if len(sys.argv) > 1 else 55,
                          sys.argv[2] if len(sys.argv) > 2 else "rig214_red_green_soil.npz",
                          KEY, COLS)
