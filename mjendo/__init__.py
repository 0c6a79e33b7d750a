"""mjendo: contact-aided navigation of a flexible robotic endoscope in a deformable, moving stomach.

Importing the package picks a headless OpenGL backend when there is no display (before MuJoCo
loads) and registers the Gymnasium ids ``mjendo/FE-v1`` ... ``mjendo/UE2-v1`` (and the previous
task's ``-v0``) and the paper's ``endogym-v0`` (DE), as Gymnasium's own packages do.
"""

from mjendo.gl import choose_backend

__version__ = "0.4.0"

choose_backend()

from mjendo.registration import register_all  # noqa: E402  (after the GL backend is chosen)

register_all()
