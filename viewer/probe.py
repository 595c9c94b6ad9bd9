"""Is offscreen rendering possible here? Asked in a subprocess, because VTK can crash the whole process
(segfault) when no OpenGL driver is present, and a crash must become a message, not a traceback.

The child renders a tiny sphere with each candidate VTK window class (EGL first, then OSMesa, which
needs the ``vtk-osmesa`` wheel; one that ``VTK_DEFAULT_OPENGL_WINDOW`` names before them, with a warning
when it fails and another works) and reports the first that draws something. The parent then sets
``VTK_DEFAULT_OPENGL_WINDOW`` to it before VTK opens a window.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

from capture.command import warn
from capture.errors import S2AError

WINDOW_ENV = "VTK_DEFAULT_OPENGL_WINDOW"
CANDIDATES = ("vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow")
DEBIAN_PACKAGES = ("libegl1", "libgl1-mesa-dri")
INSTALL_HINT = (
    "offscreen rendering is not available: install the Debian packages "
    + " ".join(DEBIAN_PACKAGES)
    + " (apt-get install -y "
    + " ".join(DEBIAN_PACKAGES)
    + "), or the VTK OSMesa wheel (pip install vtk-osmesa) where EGL cannot work"
)

_RESULT: dict | None = None


class RenderUnavailable(S2AError):
    """No OpenGL context can be made offscreen; the message says what to install."""


def _child(window: str) -> None:
    os.environ[WINDOW_ENV] = window
    import pyvista as pv

    plotter = pv.Plotter(off_screen=True, window_size=(32, 32))
    plotter.add_mesh(pv.Sphere(), color="white")
    plotter.set_background("black")
    img = plotter.screenshot(return_img=True)
    cls = plotter.ren_win.GetClassName()
    plotter.close()
    print(json.dumps({"window": cls, "nonblank": bool(img.max() > 0), "shape": list(img.shape)}))


def probe(timeout_s: float = 120.0) -> dict:
    """The first working window class as ``{"window": ..., ...}``; ``RenderUnavailable`` otherwise.

    The answer is kept for the life of the process.
    """
    global _RESULT
    if _RESULT is not None:
        return _RESULT
    tried = []
    # a window class the environment asks for (set for on-screen VTK, or misspelt) is tried first; when
    # it cannot render offscreen the candidates follow, so that it is named instead of blamed on drivers
    requested = os.environ.get(WINDOW_ENV)
    for window in dict.fromkeys((requested, *CANDIDATES) if requested else CANDIDATES):
        code = f"from viewer.probe import _child; _child({window!r})"
        try:
            proc = subprocess.run(
                [sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout_s
            )
        except subprocess.TimeoutExpired:
            tried.append(f"{window}: timed out")
            continue
        line = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
        if proc.returncode == 0 and line.startswith("{"):
            info = json.loads(line)
            if info.get("nonblank") and info.get("window") == window:
                if tried and requested:
                    why = tried[0].removeprefix(f"{requested}: ")
                    warn(f"{WINDOW_ENV}={requested} cannot render offscreen here ({why}): using {window}")
                _RESULT = info
                os.environ[WINDOW_ENV] = window
                return info
            tried.append(
                f"{window}: got {info.get('window')}, drew nothing"
                if info.get("nonblank") is False
                else f"{window}: fell back to {info.get('window')}"
            )
        else:
            how = f"signal {-proc.returncode}" if proc.returncode < 0 else f"exit {proc.returncode}"
            if proc.returncode == -11:
                how += " (segmentation fault)"
            tried.append(f"{window}: {how}")
    raise RenderUnavailable(_memory_limit() + INSTALL_HINT + " [tried: " + "; ".join(tried) + "]")


def _memory_limit() -> str:
    """What to say first when this process may use little memory (``ulimit -v``): GL drivers that run out
    of it crash as a missing driver does."""
    import resource

    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit == resource.RLIM_INFINITY or limit >= LOW_MEMORY_LIMIT:
        return ""
    return (
        f"this process may use at most {limit / 2**20:.0f} MB (ulimit -v), which a GL driver can run out of: "
        "raise the limit, or "
    )


# Below this address-space limit (bytes), a failed probe may be the limit's doing rather than a driver's.
LOW_MEMORY_LIMIT = 8 << 30


if __name__ == "__main__":
    print(json.dumps(probe()))
