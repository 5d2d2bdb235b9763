"""Cheap checks of packaging/: the PyInstaller spec, the desktop entry and icon, the build
scripts, the wheel's package list and the resources it must carry, and an sdist and wheel made
with the setuptools backend from the tracked files. The PyInstaller build itself is too slow for
the suite: packaging/build.sh and packaging/smoke_test.sh run it by hand."""

from __future__ import annotations

import configparser
import re
import shutil
import struct
import subprocess
import sys
import tarfile
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "packaging"

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def _desktop() -> configparser.SectionProxy:
    cp = configparser.ConfigParser(interpolation=None, strict=True)
    cp.optionxform = str  # keys are case-sensitive
    cp.read_string((PKG / "impress.desktop").read_text(encoding="utf-8"))
    return cp["Desktop Entry"]


def test_packaging_files_exist():
    for name in (
        "build.sh",
        "smoke_test.sh",
        "install-desktop.sh",
        "impress.spec",
        "impress_main.py",
        "impress.desktop",
        "impress.svg",
        "impress.png",
        "requirements-build.txt",
        "WINDOWS.md",
        "render_icon.py",
    ):
        assert (PKG / name).is_file(), name
    for name in ("build.sh", "smoke_test.sh", "install-desktop.sh"):
        assert (PKG / name).stat().st_mode & 0o111, f"{name} is not executable"


@pytest.mark.parametrize("script", ["build.sh", "smoke_test.sh", "install-desktop.sh"])
def test_scripts_parse(script):
    shell = "sh" if script == "install-desktop.sh" else "bash"
    res = subprocess.run([shell, "-n", str(PKG / script)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr


def test_desktop_entry():
    d = _desktop()
    assert d["Type"] == "Application"
    assert d["Name"] and d["Comment"]
    assert d["Exec"].split()[0] == "impress"
    assert d["TryExec"] == "impress"
    assert d["Terminal"] == "false"
    assert d["Icon"] == "impress"
    for key in ("Categories", "Keywords", "MimeType"):
        assert d[key].endswith(";"), key
    assert "Science" in d["Categories"].split(";")
    if shutil.which("desktop-file-validate"):
        res = subprocess.run(
            ["desktop-file-validate", str(PKG / "impress.desktop")], capture_output=True, text=True
        )
        assert res.returncode == 0, res.stdout + res.stderr


def test_desktop_entry_names_the_command_the_spec_builds():
    spec = (PKG / "impress.spec").read_text(encoding="utf-8")
    app_name = re.search(r'^APP_NAME = "([^"]+)"', spec, re.M).group(1)
    assert _desktop()["Exec"].split()[0] == app_name
    assert app_name in _pyproject()["project"]["scripts"]
    # the install script rewrites exactly these two lines to the bundle's absolute path
    text = (PKG / "impress.desktop").read_text(encoding="utf-8")
    assert re.search(r"^Exec=impress ", text, re.M) and re.search(r"^TryExec=impress$", text, re.M)
    install = (PKG / "install-desktop.sh").read_text(encoding="utf-8")
    assert "s|^Exec=impress |" in install and "s|^TryExec=impress$|" in install


def test_icon_files():
    root = ET.parse(PKG / "impress.svg").getroot()
    assert root.tag.endswith("svg")
    assert root.get("viewBox") == "0 0 256 256"
    png = (PKG / "impress.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", png[16:24])
    assert (width, height) == (256, 256)


def test_spec_is_consistent_with_the_tree():
    spec = (PKG / "impress.spec").read_text(encoding="utf-8")
    # the entry script, icon files and resources it names exist
    assert 'HERE / "impress_main.py"' in spec and (PKG / "impress_main.py").is_file()
    for icon in ("impress.png", "impress.svg"):
        assert f'HERE / "{icon}"' in spec
    # resources go where impress_gui.core.calibration.target.resources_dir() looks in an installed package
    assert '(str(ROOT / "resources"), "impress_gui/resources")' in spec
    assert (ROOT / "resources" / "targets" / "l_target_v1.json").is_file()
    # subcommands are imported by name at run time: the spec must take every module
    assert 'collect_submodules("impress_gui")' in spec
    entry = (PKG / "impress_main.py").read_text(encoding="utf-8")
    assert "freeze_support()" in entry and "from impress_gui.cli import main" in entry
    compile(spec, "impress.spec", "exec")
    # the one-folder bundle's executable is what build.sh and smoke_test.sh run
    assert "dist/impress/impress" in (PKG / "smoke_test.sh").read_text(encoding="utf-8")
    assert "packaging/impress.spec" in (PKG / "build.sh").read_text(encoding="utf-8")


def test_build_requirements_are_pinned_and_agree_with_constraints():
    pins = {}
    for line in (PKG / "requirements-build.txt").read_text(encoding="utf-8").splitlines():
        line = line.split("#")[0].strip()
        if line:
            m = re.fullmatch(r"([A-Za-z0-9_.-]+)==([0-9][0-9A-Za-z.]*)", line)
            assert m, f"not pinned with ==: {line!r}"
            pins[m.group(1).lower().replace("_", "-")] = m.group(2)
    assert {"pyinstaller", "pyinstaller-hooks-contrib", "build", "setuptools", "wheel"} <= set(pins)
    constraints = {}
    for line in (ROOT / "constraints.txt").read_text(encoding="utf-8").splitlines():
        if "==" in line:
            name, ver = line.split("#")[0].strip().split("==")
            constraints[name.lower().replace("_", "-")] = ver
    both = set(pins) & set(constraints)
    assert all(pins[n] == constraints[n] for n in both), {
        n: (pins[n], constraints[n]) for n in both
    }
    # the build backend the wheel needs
    requires = _pyproject()["build-system"]["requires"]
    assert any(r.startswith("setuptools") for r in requires)


def test_build_venv_and_outputs_are_ignored():
    paths = ["packaging/.venv-build/bin/python", "dist/impress/impress", "build/pyinstaller/x"]
    res = subprocess.run(["git", "check-ignore", *paths], cwd=ROOT, capture_output=True, text=True)
    if res.returncode == 128:
        pytest.skip("not a git checkout")
    assert res.stdout.split() == paths


def _package_dirs() -> set[str]:
    return {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in (ROOT / "impress_gui").rglob("__init__.py")
        if "__pycache__" not in p.parts
    }


def test_wheel_package_list_matches_the_source_tree():
    st = _pyproject()["tool"]["setuptools"]
    listed = set(st["packages"])
    assert listed - {"impress_gui.resources"} == _package_dirs(), (
        "pyproject.toml [tool.setuptools] packages must list every package of impress_gui "
        "(a new subpackage must be added there, or the wheel and the bundle lack it)"
    )
    assert st["package-dir"]["impress_gui.resources"] == "resources"
    assert st["package-data"]["impress_gui.resources"]


def test_resources_are_found_in_an_installed_layout(tmp_path):
    """The wheel's and the bundle's layout: <site>/impress_gui/resources, no source tree."""
    site = tmp_path / "site"
    shutil.copytree(
        ROOT / "impress_gui", site / "impress_gui", ignore=shutil.ignore_patterns("__pycache__")
    )
    shutil.copytree(ROOT / "resources", site / "impress_gui" / "resources")
    code = (
        "from impress_gui.core.calibration.target import default_target, resources_dir\n"
        "print(resources_dir()); print(default_target().name)"
    )
    res = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={"PYTHONPATH": str(site), "PATH": "/usr/bin:/bin"},
    )
    assert res.returncode == 0, res.stderr
    where, name = res.stdout.split("\n")[:2]
    assert Path(where) == site / "impress_gui" / "resources"
    assert name == "IMPREsS L target v1"


def _tracked_copy(dst: Path) -> None:
    res = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True)
    if res.returncode != 0:
        pytest.skip("not a git checkout")
    for rel in res.stdout.decode().split("\0"):
        src = ROOT / rel
        if rel and src.is_file():
            (dst / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst / rel)


BUILD = """
import importlib.util, sys
import setuptools
from setuptools import build_meta as backend
out = sys.argv[1]
print(backend.build_sdist(out))
# setuptools < 70.1 builds wheels only with the wheel package
v = tuple(int(x) for x in setuptools.__version__.split(".")[:2])
can_wheel = v >= (70, 1) or importlib.util.find_spec("wheel") is not None
print(backend.build_wheel(out) if can_wheel else "-")
"""


def test_sdist_and_wheel_from_the_tracked_files(tmp_path):
    """What `python -m build` makes (same backend, without an isolated environment): the sdist
    carries resources/, the wheel carries it as impress_gui/resources and the entry point."""
    pytest.importorskip("setuptools")
    src = tmp_path / "src"
    _tracked_copy(src)
    out = tmp_path / "out"
    out.mkdir()
    res = subprocess.run(
        [sys.executable, "-c", BUILD, str(out)],
        cwd=src,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    sdist_name, wheel_name = res.stdout.strip().splitlines()[-2:]
    with tarfile.open(out / sdist_name) as tf:
        names = {n.split("/", 1)[1] for n in tf.getnames() if "/" in n}
    assert "resources/targets/l_target_v1.json" in names
    assert "impress_gui/cli.py" in names and "pyproject.toml" in names
    if wheel_name == "-":
        pytest.skip("sdist checked; no wheel: this setuptools needs the wheel package")
    with zipfile.ZipFile(out / wheel_name) as zf:
        wnames = set(zf.namelist())
        entry = next(n for n in wnames if n.endswith(".dist-info/entry_points.txt"))
        assert "impress = impress_gui.cli:main" in zf.read(entry).decode()
    assert "impress_gui/resources/targets/l_target_v1.json" in wnames
    for pkg in _package_dirs():
        assert pkg.replace(".", "/") + "/__init__.py" in wnames, pkg
    assert not any(n.startswith(("tests/", "resources/", "docs/")) for n in wnames)
