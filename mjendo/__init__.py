"""mjendo: contact-aided navigation of a flexible robotic endoscope in a deformable, moving stomach.

Importing the package picks a headless OpenGL backend when there is no
display (before MuJoCo loads) and registers the Gymnasium ids
``mjendo/FE-v0`` ... ``mjendo/UE2-v0`` and the paper's ``endogym-v0`` (DE).
"""

from mjendo.gl import choose_backend

__version__ = "0.1.0"

choose_backend()


def _register() -> None:
    from mjendo.envs import register_all

    register_all()


_register()
