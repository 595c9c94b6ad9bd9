"""Set-ups other than the README's editable ``.venv``: the project installed from its wheel (as ``pip install
.`` or ``pip install git+URL`` build one) and run from a folder outside the checkout, and a checkout in a
folder whose path has spaces and accents, run in the POSIX locale with no home folder. Real builds and real
subprocesses; the copies are made under pytest's temporary folder, never in the checkout."""

from __future__ import annotations

import configparser
import email.parser
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from conftest import ROOT, run_cli

PACKAGES = ("capture", "align", "dataset", "train", "viewer")
SCRIPTS = {
    "s2a-capture": "capture.cli:main",
    "s2a-align": "align.cli:main",
    "s2a-dataset": "dataset.cli:main",
    "s2a-train": "train.cli:main",
    "s2a-view": "viewer.cli:main",
}
PIP = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
SHORT_TAKE = ["--seconds", 2, "--sample-rate", 16000]  # a simulated take of 2 s at 16 kHz


def copy_source(dest: Path) -> Path:
    """The files a build or a clone needs (the stage packages, pyproject.toml, README.md, LICENSE) copied
    to ``dest``: a build there leaves nothing (``build/``, ``*.egg-info``) in the checkout."""
    dest.mkdir(parents=True)
    for package in PACKAGES:
        shutil.copytree(ROOT / package, dest / package, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, dest / name)
    return dest


def modules_of(root: Path) -> set[str]:
    return {
        p.relative_to(root).as_posix()
        for package in PACKAGES
        for p in (root / package).rglob("*.py")
        if "__pycache__" not in p.parts
    }


def run(cmd: list, cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    proc = subprocess.run(
        [str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, (
        cmd,
        proc.returncode,
        proc.stderr[-3000:],
    )
    return proc


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The project's wheel, built from a copy of the checkout as ``pip wheel`` builds it."""
    try:
        import setuptools
    except ImportError:
        pytest.skip("setuptools is not installed: no wheel can be built without build isolation")
    if int(setuptools.__version__.split(".")[0]) < 77:
        pytest.skip(f"setuptools {setuptools.__version__} is older than the 77 pyproject.toml needs")
    root = tmp_path_factory.mktemp("wheel")
    src = copy_source(root / "src")
    run(
        [*PIP, "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", root / "dist", src],
        root,
        dict(os.environ),
    )
    (built,) = (root / "dist").glob("s2a_toolkit-*.whl")
    return built


def test_the_wheel_holds_every_module_and_right_metadata(wheel):
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        (dist_info,) = {n.split("/")[0] for n in names if n.split("/")[0].endswith(".dist-info")}
        meta = email.parser.Parser().parsestr(z.read(f"{dist_info}/METADATA").decode())
        entry_points = configparser.ConfigParser()
        entry_points.read_string(z.read(f"{dist_info}/entry_points.txt").decode())
    # every module of the checkout, a subfolder without __init__.py too, and nothing else
    assert {n for n in names if not n.startswith(dist_info)} == modules_of(ROOT)
    assert meta["License-Expression"] == "MIT" and meta["License-File"] == "LICENSE"
    assert f"{dist_info}/licenses/LICENSE" in names
    assert meta["Description-Content-Type"] == "text/markdown"
    assert meta.get_payload().strip() == (ROOT / "README.md").read_text(encoding="utf-8").strip()
    assert dict(entry_points["console_scripts"]) == SCRIPTS
    # train.config falls back to tomli below Python 3.11 (no tomllib there): it must be installed with it
    requires = meta.get_all("Requires-Dist")
    assert any(r.startswith("tomli") and 'python_version < "3.11"' in r for r in requires), requires


def test_commands_run_from_the_installed_wheel_outside_the_checkout(wheel, tmp_path):
    """``pip install`` (not editable) of the wheel, its commands run from another folder: the modules come
    from the install, the console scripts start, and a take is simulated, imported and aligned."""
    site = tmp_path / "site"
    env = dict(os.environ)
    run([*PIP, "install", "-q", "--no-deps", "--target", site, wheel], tmp_path, env)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env["PYTHONPATH"] = str(site)
    where = run(
        [sys.executable, "-c", "import capture, train; print(capture.__file__, train.__file__)"],
        elsewhere,
        env,
    )
    assert all(Path(f).is_relative_to(site) for f in where.stdout.split()), where.stdout
    assert {p.name for p in (site / "bin").iterdir()} >= set(SCRIPTS)
    run([site / "bin" / "s2a-capture", "simulate", "-o", "sim", *SHORT_TAKE, "--mov"], elsewhere, env)
    run([sys.executable, "-m", "capture", "import", "sim", "-o", "takes"], elsewhere, env)
    (take,) = (elsewhere / "takes").iterdir()
    proc = run([site / "bin" / "s2a-align", take, "-o", "aligned", "--json"], elsewhere, env)
    assert json.loads(proc.stdout.splitlines()[0])["id"] == take.name
    assert (elsewhere / "aligned" / take.name / "frames.npz").is_file()


def test_a_checkout_under_spaces_and_accents_in_the_posix_locale(tmp_path):
    """A clone in ``~/My Projects/Téléchargements s2a``, run with ``LC_ALL=C``, no ``LANG``, no home
    folder, ``TERM=dumb``, stdout a pipe: the commands read and write paths with accents and print them."""
    clone = copy_source(tmp_path / "My Projects" / "Téléchargements s2a")
    env = {
        k: v for k, v in os.environ.items() if k not in ("HOME", "LANG", "PYTHONIOENCODING", "MPLCONFIGDIR")
    }
    env.update(LC_ALL="C", TERM="dumb", PYTHONDONTWRITEBYTECODE="1")
    where = run([sys.executable, "-c", "import capture; print(capture.__file__)"], clone, env)
    assert Path(where.stdout.strip()).is_relative_to(clone), where.stdout
    out = clone / "prises de vue é"
    run([sys.executable, "-m", "capture", "simulate", "-o", out, *SHORT_TAKE], clone, env)
    proc = run(
        [sys.executable, "-m", "capture", "import", out, "-o", clone / "takes à", "--json"], clone, env
    )
    (line,) = proc.stdout.splitlines()
    (take,) = (clone / "takes à").iterdir()
    assert json.loads(line)["id"] == take.name
    proc = run(
        [
            sys.executable,
            "-m",
            "viewer",
            "plot",
            take,
            "-o",
            clone / "courbes é.png",
            "--channels",
            "jawOpen",
        ],
        clone,
        env,
    )
    assert (clone / "courbes é.png").stat().st_size > 0


def test_make_clean_removes_the_staged_build(tmp_path):
    """``pip install .`` and ``pip wheel .`` stage the modules in ``build/`` and pack what is there: a module
    removed from the checkout since the last build went into the next wheel. ``make clean`` removes it."""
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    shutil.copy2(ROOT / "Makefile", tmp_path / "Makefile")
    stale = tmp_path / "build" / "lib" / "capture" / "removed_since.py"
    stale.parent.mkdir(parents=True)
    stale.write_text("GONE = True\n")
    run(["make", "--no-print-directory", "clean"], tmp_path, dict(os.environ))
    assert not (tmp_path / "build").exists()


def test_result_lines_on_an_ascii_stdout(sim_take, tmp_path):
    """``PYTHONUTF8=0 LC_ALL=C`` (Python's ASCII locale; ``PYTHONIOENCODING=ascii`` alike): a result line
    naming a folder with an accent was a UnicodeEncodeError traceback after the work was done (s2a-capture
    info, s2a-dataset build and validate); the character is shown as ``\\xe9`` instead, as on stderr."""
    takes = tmp_path / "prises é"
    run_cli("capture", "import", sim_take, "-o", takes, check=True)
    env = dict(os.environ, LC_ALL="C", PYTHONUTF8="0", PYTHONCOERCECLOCALE="0")
    env.pop("PYTHONIOENCODING", None)
    proc = run([sys.executable, "-m", "capture", "info", takes], ROOT, env)
    assert "prises \\xe9" in proc.stdout


def test_fit_into_a_folder_whose_name_is_not_utf8(built, tmp_path):
    """``s2a-train fit -o`` a folder whose name's bytes are Latin-1 (``caf\\xe9``, another system's): the
    run was a UnicodeEncodeError traceback from TensorBoard's writer; it trains with metrics.jsonl only."""
    run_dir = Path(os.fsdecode(bytes(tmp_path) + b"/caf\xe9"))
    sets = [
        a for s in ["arch.d_model=32", "arch.heads=2", "arch.ff_dim=64", "window=120"] for a in ("--set", s)
    ]
    proc = run_cli("train", "fit", "--data", built, "-o", run_dir, "--max-steps", 2, *sets)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert "caf\\xe9" in proc.stderr and (run_dir / "best.pt").is_file()


def test_make_deb_as_a_normal_user_names_the_command(tmp_path):
    """``make deb`` (run by ``make test`` and ``make demo``) as a user who is not root, with a package
    missing: it says which, and the command that installs it, and goes on (root installs it instead)."""
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    drop = []
    if os.geteuid() == 0:
        drop = ["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups"]
        if shutil.which("setpriv") is None or subprocess.run([*drop, "true"]).returncode:
            pytest.skip("cannot run a command as a normal user here")
    tmp_path.chmod(0o755)
    shutil.copy2(ROOT / "Makefile", tmp_path / "Makefile")
    (tmp_path / "Makefile").chmod(0o644)
    missing = "s2a-no-such-package"
    proc = run(
        [*drop, "make", "--no-print-directory", "deb", f"DEB_PACKAGES={missing}"], tmp_path, dict(os.environ)
    )
    assert f"sudo apt-get install {missing}" in proc.stdout, proc.stdout
