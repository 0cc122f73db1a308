"""samp: spatial-anchor motion policies for robot arms."""

__version__ = "0.1.0"
__all__ = ["__version__"]
