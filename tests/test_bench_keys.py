"""The benchmarks' render cache is keyed by the simulator's sources: every module of ours the
simulator imports must be among them, or a change there keeps serving stale renders."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _covered(rel: str, parts: tuple[str, ...]) -> bool:
    return any(rel == p or rel.startswith(p.rstrip("/") + "/") for p in parts)


def test_sim_key_covers_every_module_the_simulator_imports():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import common
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    code = ("import sys, impress_gui.sim.simulate, impress_gui.sim.truth\n"
            "for m in list(sys.modules.values()):\n"
            "    f = getattr(m, '__file__', None)\n"
            "    if m.__name__.startswith('impress_gui') and f: print(f)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT).stdout.splitlines()
    files = sorted({Path(f).resolve().relative_to(ROOT).as_posix() for f in out})
    assert any(f.startswith("impress_gui/sim/") for f in files)
    missing = [f for f in files if not _covered(f, common.SIM_SOURCES)]
    assert not missing, f"SIM_SOURCES leaves out modules the simulator imports: {missing}"
    # every part names something (a part that names nothing would hash nothing)
    for part in common.SIM_SOURCES:
        assert (ROOT / part).exists(), part
