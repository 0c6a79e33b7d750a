"""mjendo: contact-aided navigation of a flexible robotic endoscope in a deformable, moving stomach.

Importing the package picks a headless OpenGL backend when there is no
display (before MuJoCo loads) and registers the Gymnasium ids
``mjendo/FE-v0`` ... ``mjendo/UE2-v0`` and the paper's ``endogym-v0`` (DE).
Nothing else is loaded: ``import mjendo.units`` pulls in neither MuJoCo nor
Gymnasium (see :mod:`mjendo.registration`).
"""

from mjendo.gl import choose_backend
from mjendo.registration import register_when_gymnasium_loads

__version__ = "0.2.0"

choose_backend()
register_when_gymnasium_loads()
