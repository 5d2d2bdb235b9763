"""IMPREsS workstation: forensic impression 3D laser-scanner software."""

__version__ = "0.1.0"
