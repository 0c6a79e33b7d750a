"""mjendo: contact-aided navigation of a flexible robotic endoscope in a deformable, moving stomach."""

__version__ = "0.1.0"
