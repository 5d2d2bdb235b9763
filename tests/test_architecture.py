"""The Qt-free core stays Qt-free, and the command line stays light."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_import_linter_contract_holds():
    lint = Path(sys.executable).with_name("lint-imports")
    res = subprocess.run([str(lint)], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "KEPT" in res.stdout


def test_core_type_checks():
    """mypy on the Qt-free core (configured in pyproject.toml): no errors."""
    mypy = Path(sys.executable).with_name("mypy")
    res = subprocess.run([str(mypy), "--no-error-summary", "--cache-dir", str(ROOT / ".mypy_cache")],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr


BLOCK_QT = """
import sys, importlib, pkgutil
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('PySide6', 'pyqtgraph', 'shiboken6'):
            raise ImportError('Qt is blocked in this test: ' + name)
sys.meta_path.insert(0, Block())
import impress_gui
for pkg in ('core', 'sim', 'hardware', 'commands'):
    mod = importlib.import_module('impress_gui.' + pkg)
    for info in pkgutil.walk_packages(mod.__path__, mod.__name__ + '.'):
        if info.name in ('impress_gui.commands.gui',):
            continue
        importlib.import_module(info.name)
print('ok')
"""


def test_core_imports_with_qt_unimportable():
    res = subprocess.run([sys.executable, "-c", BLOCK_QT], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().endswith("ok")


def test_help_is_fast_and_loads_no_heavy_modules():
    code = (
        "import sys, contextlib, io\n"
        "from impress_gui.cli import main\n"
        "buf = io.StringIO()\n"
        "with contextlib.redirect_stdout(buf):\n"
        "    try:\n"
        "        main(['--help'])\n"
        "    except SystemExit:\n"
        "        pass\n"
        "heavy = [m for m in ('PySide6', 'open3d', 'cv2', 'av', 'pyqtgraph', 'numpy', 'numba',\n"
        "                     'scipy', 'cryptography', 'psygnal') if m in sys.modules]\n"
        "ours = sorted(m for m in sys.modules if m.startswith('impress_gui'))\n"
        "print(heavy, ours, len(sys.modules))\n"
        "assert 'simulate' in buf.getvalue()\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    loaded, n = res.stdout.strip().rsplit(" ", 1)[0], int(res.stdout.split()[-1])
    # what --help loads (not how long that takes on a busy machine): the command table only,
    # no library of the work itself and about the standard library's argparse
    # (quiet: the console's filter of library warnings, standard library only)
    assert loaded == ("[] ['impress_gui', 'impress_gui.cli', 'impress_gui.core', "
                      "'impress_gui.core.base', 'impress_gui.core.base.codes', "
                      "'impress_gui.core.base.quiet']"), res.stdout
    assert n < 150, f"--help loads {n} modules"


def test_python_dash_m_entry_point():
    res = subprocess.run(
        [sys.executable, "-m", "impress_gui", "--version"], capture_output=True, text=True
    )
    assert res.returncode == 0
    assert res.stdout.startswith("impress ")


def test_every_module_lives_in_its_layer():
    """core/ holds concept packages only; every module under ui/ is Qt code, or built on it
    (Qt-free code belongs to session/ or core/); the layers' packages are where
    docs/architecture.md says."""
    pkg = ROOT / "impress_gui"
    loose = sorted(p.name for p in (pkg / "core").glob("*.py") if p.name != "__init__.py")
    assert loose == [], f"modules in core/ outside a concept package: {loose}"
    qt_free = sorted(
        str(p.relative_to(pkg)) for p in (pkg / "ui").rglob("*.py")
        if p.name != "__init__.py"
        and not any(s in p.read_text()
                    for s in ("from PySide6", "import pyqtgraph", "from impress_gui.ui"))
    )
    assert qt_free == [], f"Qt-free modules under ui/: {qt_free}"
    for layer in ("core", "session", "validation", "sim", "hardware", "ui", "commands"):
        assert (pkg / layer / "__init__.py").is_file(), layer


def test_error_codes_are_named_once():
    """Every E-/W- code is a constant in core/base/codes.py; code elsewhere uses the names."""
    import re

    from impress_gui.core.base import codes

    literal = re.compile(r"""(?<![\w\\])(["'])([EW]-[A-Z0-9]+(?:-[A-Z0-9]+)*)\1""")
    pkg = ROOT / "impress_gui"
    found = [f"{p.relative_to(pkg)}: {m.group(2)}" for p in pkg.rglob("*.py")
             if p.name != "codes.py" for m in literal.finditer(p.read_text())]
    assert found == []
    names = {k: v for k, v in vars(codes).items() if k[:2] in ("E_", "W_")}
    assert len(names) > 50 and all(v == k.replace("_", "-") for k, v in names.items())
