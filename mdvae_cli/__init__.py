"""mdvae: clean up human motion-capture files with a learned Motion-DVAE prior."""

__version__ = "0.1.0"
