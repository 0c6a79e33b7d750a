"""Pick an OpenGL backend before MuJoCo is imported: a display if there is one, else EGL, else OSMesa."""

from __future__ import annotations

import ctypes.util
import os


class NoOpenGLError(RuntimeError):
    """No OpenGL backend could render; the message names the package to install."""


NO_GL_HELP = ("no OpenGL backend for headless rendering: install EGL (Debian/Ubuntu: "
              "`apt-get install libegl1`) or OSMesa (`apt-get install libosmesa6`, then MUJOCO_GL=osmesa); "
              "if mujoco was imported before mjendo, set MUJOCO_GL=egl before starting Python")


def choose_backend() -> str | None:
    """Set MUJOCO_GL unless the user did; returns the choice (None: nothing usable found)."""
    if os.environ.get("MUJOCO_GL"):
        return os.environ["MUJOCO_GL"]
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None  # MuJoCo's default (GLFW) uses the display
    for backend, lib in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(lib):
            os.environ["MUJOCO_GL"] = backend
            # PyOpenGL must agree with MuJoCo on the platform.
            os.environ.setdefault("PYOPENGL_PLATFORM", backend)
            return backend
    return None
