"""`pip install .` (pyproject.toml): the wheel holds every package and the scene files, and the
installed `taichi-soft` command runs from outside the checkout."""
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile

from conftest import ROOT


def test_every_package_folder_is_listed_in_pyproject():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "taichi_soft").rglob("__init__.py")}
    assert found - listed == set(), "package folders missing from pyproject.toml's packages"
    assert listed - found == {"taichi_soft.scenes"}, "pyproject.toml lists packages that do not exist"


def test_installed_package_has_scenes_and_command(tmp_path):
    src = tmp_path / "src"  # a copy, so the build's build/ and egg-info do not land in the checkout
    for name in ("taichi_soft", "scenes"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path / "dist"), str(src)],
                   check=True, capture_output=True)
    (wheel,) = (tmp_path / "dist").glob("taichi_soft-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for scene in (ROOT / "scenes").glob("*.toml"):
        assert f"taichi_soft/scenes/{scene.name}" in names
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(wheel)],
                   check=True, capture_output=True)
    # Run the installed command from an empty folder with only the installed copy importable.
    env = dict(os.environ, PYTHONPATH=str(target))
    run = tmp_path / "cwd"
    run.mkdir()
    out = subprocess.run([sys.executable, str(target / "bin" / "taichi-soft"), "list"], cwd=run, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert str(target / "taichi_soft" / "scenes") in out.stdout
    assert "plane" in out.stdout and "tilted_plane" in out.stdout


def test_pip_install_with_its_dependencies_runs_a_mesh_scene_and_usd_export(tmp_path):
    """`pip install .` into a fresh venv, dependencies from pyproject.toml only (pinned to the
    versions this suite runs on, so pip's cache serves them), then in an empty folder the torus
    mesh scene exported to USD: trimesh, its helpers and usd-core must come with the package."""
    src = tmp_path / "src"
    for name in ("taichi_soft", "scenes"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, capture_output=True)
    freeze = subprocess.run([sys.executable, "-m", "pip", "freeze", "--exclude-editable"], check=True,
                            capture_output=True, text=True).stdout
    pins = tmp_path / "pins.txt"
    pins.write_text("\n".join(line for line in freeze.splitlines() if "==" in line) + "\n")
    done = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                           "-c", str(pins), str(src)], capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    run = tmp_path / "cwd"
    run.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([str(venv / "bin" / "taichi-soft"), "run", "--scene", "torus", "--export-usd", "t.usd",
                          "--duration", "1"], cwd=run, env=env, capture_output=True, text=True,
                         timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    usd = (run / "t.usd").read_bytes()
    assert usd.startswith(b"PXR-USDC") or usd.startswith(b"#usda"), usd[:16]
