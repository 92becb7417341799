"""Grid build strategies; importing this package registers each one (explicitly, by name)."""

from . import serial  # noqa: F401
