"""less: learned tactile imaging with local scene representations."""

__version__ = "0.1.0"
